"""Directories the project writes its results into (run directories, campaigns, replays, figures): made
where the user said, or a :class:`~protocol.errors.ConfigError` naming the path and why not — a path
under a file, one too long for the file system, a read-only place — never an ``OSError``'s traceback."""

from __future__ import annotations

import os
from pathlib import Path

from protocol.errors import ConfigError, HilError

MAX_LABEL = 64
"""Characters of a name-derived label kept in a directory's name (a scenario's name may be long; a file
system's name is at most 255 bytes)."""


def make_dir(path: str | os.PathLike[str], exist_ok: bool = True) -> Path:
    """``path`` as a directory, with its parents; ``FileExistsError`` when it exists and not
    ``exist_ok`` (the caller picks another name); any other failure a ConfigError naming it."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=exist_ok)
    except FileExistsError:
        if out.is_dir():  # not exist_ok: the caller picks another name
            raise
        raise ConfigError("cannot make a directory here: a file of that name exists", str(out)) from None
    except OSError as exc:
        raise ConfigError(f"cannot make this directory: {exc.strerror or exc}", str(out)) from exc
    return out


def safe_label(label: str) -> str:
    """``label`` as a part of a directory's name: characters other than letters, digits and ``-_.``
    replaced, at most :data:`MAX_LABEL` of them."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in label)[:MAX_LABEL]
    return safe or "run"


class OutputError(HilError, OSError):
    """A result file (a run's telemetry, events or summary) that the operating system refused to write: a
    full disk (ENOSPC), a file-size limit (EFBIG), an I/O error, a directory removed or replaced under the
    run. Says which file and why; an :class:`OSError` too, with the refusal's ``errno``, so a caller that
    handles the OS's errors handles it."""

    def __init__(self, path: str | os.PathLike[str], error: OSError) -> None:
        super().__init__(error.errno, f"cannot write {path}: {error.strerror or error}")
        self.path = Path(path)

    def __str__(self) -> str:
        return str(self.strerror)


def write_file(path: str | os.PathLike[str], text: str) -> None:
    """``text`` as the whole of ``path``; an :class:`OutputError` naming it when the OS refuses."""
    try:
        Path(path).write_text(text)
    except OSError as exc:
        raise OutputError(path, exc) from exc
