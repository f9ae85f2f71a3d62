"""Appending whole lines to a result file: never a torn one.

A run's ``telemetry.csv`` and ``events.jsonl`` grow while it runs. When the operating system refuses part of
a write — a full disk (ENOSPC), a file-size limit (EFBIG), an I/O error — a buffered text file leaves a torn
last line behind and keeps the rest in its buffer, which every later flush and the final ``close()`` try
(and fail) to write again: the error is raised a second time from the run's clean-up, where it hides the
first one and stops the summary from being written. :class:`LineAppender` writes unbuffered, and on a
refusal cuts the file back to the end of the last whole line that reached it and raises an
:class:`OutputError` naming the file, so the file always ends at a whole line (keeping every line that
fitted) and closing it never fails on data it held back.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from hil.files.output import OutputError


class LineAppender:
    """``path`` opened for writing whole lines (``mode`` ``"w"``: a new file, ``"a"``: appended to). Each
    :meth:`write` goes to the OS at once; :attr:`size` is where the last whole write ended (bytes)."""

    def __init__(self, path: str | os.PathLike[str], mode: str = "w") -> None:
        if mode not in ("w", "a"):
            raise ValueError(f"mode must be 'w' or 'a', got {mode!r}")
        self.path = Path(path)
        try:
            self._file = open(self.path, mode + "b", buffering=0)  # noqa: SIM115 — closed by close()
        except OSError as exc:
            raise OutputError(self.path, exc) from exc
        self.size = self._file.seek(0, os.SEEK_END)

    def write(self, data: bytes) -> None:
        """Append ``data`` (whole lines). When the OS refuses part of it, the file is cut back to the end
        of the last whole line that reached it (:attr:`size` moves on to there: ``data[:size - size
        before]`` is what was kept) and an :class:`OutputError` is raised. Anything else that stops the
        write half-way (an interrupt between two partial writes) cuts it back the same way, then goes on
        as it was."""
        view = memoryview(data)
        done = 0
        try:
            while done < len(data):
                done += self._file.write(view[done:]) or 0
        except OSError as exc:
            self._cut(data, done)
            raise OutputError(self.path, exc) from exc
        except BaseException:
            self._cut(data, done)
            raise
        self.size += len(data)

    def _cut(self, data: bytes, done: int) -> None:
        """The file back to the end of the last whole line of ``data[:done]`` (what reached it); best
        effort: a file that cannot even be cut keeps its torn tail, which the readers drop and count."""
        self.size += data.rfind(b"\n", 0, done) + 1
        with contextlib.suppress(OSError):
            os.ftruncate(self._file.fileno(), self.size)
            self._file.seek(self.size)

    def close(self) -> None:
        """Close the file (nothing is held back to be written). Idempotent."""
        self._file.close()

    @property
    def closed(self) -> bool:
        return self._file.closed
