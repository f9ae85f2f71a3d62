"""Where the project's own data lives (the checkout is installed in editable mode)."""

from __future__ import annotations

from pathlib import Path

from protocol.errors import ConfigError, HilError

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"
SHARED_DATA = ROOT.parent / "shared" / "data"
"""Real recorded sensor data (read-only, beside the checkout; see its README)."""


def read_text(path: Path, error: type[HilError] = ConfigError, what: str = "") -> str:
    """A text file the project reads (scenario, dispersions, a run directory's files) as UTF-8; an
    unreadable or binary one is one ``error`` naming the file, never a traceback."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"cannot read{' ' + what if what else ''}: {exc.strerror}", str(path)) from exc
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(f"not a text file (not UTF-8: {exc.reason} at byte {exc.start})", str(path)) from None
