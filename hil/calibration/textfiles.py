"""Reading and writing the calibration package's text files: typed errors that name the file, and atomic
writes (a reader never sees half a calibration file)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from pathlib import Path

from hil.files.bounded import MAX_DOCUMENT_BYTES, read_document
from protocol.errors import ConfigError, HilError


def read_text(path: str | os.PathLike[str], error: Callable[[str, str], HilError]) -> str:
    """The UTF-8 text of ``path``, at most :data:`~hil.files.bounded.MAX_DOCUMENT_BYTES` (a calibration
    file or a bench CSV is a few kB); ``error(detail, path)`` is raised when it is missing, unreadable,
    not text or larger (:func:`hil.files.bounded.read_document`)."""
    return read_document(path, error, limit=MAX_DOCUMENT_BYTES)


def write_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file renamed over it; creates the directory.
    :class:`ConfigError` naming the file if it cannot be written."""
    out = Path(path)
    tmp = out.with_name(out.name + ".tmp")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, out)
    except OSError as exc:
        if tmp.is_file():  # written but not renamed (the target a folder, say): not left behind
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise ConfigError(f"cannot write: {exc.strerror or exc}", str(path)) from exc
    return out


def check_writable(path: str | os.PathLike[str], where: str | None = None) -> Path:
    """Refuse, before any work (a board driven, a sweep run), a file that :func:`write_atomic` could not
    write or that reading would hang on: ``path`` exists but is not a regular file (a folder, a FIFO — a
    read of which waits for a writer for ever —, a device), or its folder cannot be made or written (a
    parent that is a regular file, a read-only folder). :class:`ConfigError` naming ``where`` (default:
    the path). Nothing is created."""
    out = Path(path)
    said = where if where is not None else str(out)
    if out.exists() or out.is_symlink():
        if not out.is_file():
            kind = "a folder" if out.is_dir() else "not a regular file (a FIFO, a device or a socket)"
            raise ConfigError(f"cannot write {out}: {kind}", said)
    folder = out.parent
    while not folder.exists():
        if folder.is_symlink():  # a dangling link: mkdir would fail
            raise ConfigError(f"cannot write {out}: {folder} is a broken link", said)
        folder = folder.parent
    if not folder.is_dir():
        raise ConfigError(f"cannot write {out}: {folder} is not a folder", said)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"cannot write {out}: the folder {folder} is not writable", said)
    return out
