"""Where the project's own data lives (the checkout is installed in editable mode)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"
SHARED_DATA = ROOT.parent / "shared" / "data"
"""Real recorded sensor data (read-only, beside the checkout; see its README)."""
