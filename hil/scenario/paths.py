"""Where the project's own data lives (the checkout is installed in editable mode)."""

from __future__ import annotations

from pathlib import Path

from hil.files.bounded import read_document
from protocol.errors import ConfigError, HilError

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"
SHARED_DATA = ROOT.parent / "shared" / "data"
"""Real recorded sensor data (read-only, beside the checkout; see its README)."""


def read_text(
    path: Path, error: type[HilError] = ConfigError, what: str = "", limit: int | None = None
) -> str:
    """A text file the project reads (scenario, dispersions, a run directory's files) as UTF-8, at most
    ``limit`` bytes (None: no limit, for a file bounded by how it is used, e.g. a campaign's results); an
    unreadable, binary or larger one is one ``error`` naming the file, never a traceback
    (:func:`hil.files.bounded.read_document`)."""
    return read_document(path, error, what, limit)  # type: ignore[arg-type]
