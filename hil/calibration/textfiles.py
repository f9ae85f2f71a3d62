"""Reading and writing the calibration package's text files: typed errors that name the file, and atomic
writes (a reader never sees half a calibration file)."""

from __future__ import annotations

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
        raise ConfigError(f"cannot write: {exc.strerror or exc}", str(path)) from exc
    return out
