"""Reading and writing the calibration package's text files: typed errors that name the file, and atomic
writes (a reader never sees half a calibration file)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from protocol.errors import ConfigError, HilError


def read_text(path: str | os.PathLike[str], error: Callable[[str, str], HilError]) -> str:
    """The UTF-8 text of ``path``; ``error(detail, path)`` is raised when it is missing or unreadable."""
    p = str(path)
    try:
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise error("no such file", p) from exc
    except UnicodeDecodeError as exc:
        raise error(f"not UTF-8 text ({exc.reason} at byte {exc.start})", p) from exc
    except OSError as exc:
        raise error(f"cannot read: {exc.strerror or exc}", p) from exc


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
