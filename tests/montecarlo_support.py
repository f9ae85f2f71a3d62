"""The campaigns' tests' short scenario (tests/test_montecarlo.py, tests/test_montecarlo_hostile.py)."""

from __future__ import annotations

from pathlib import Path

from hil.scenario import SCENARIO_DIR


def write_quick_scenario(directory: Path) -> Path:
    """cubesat-1u, shortened: 0.5 s warm-up, a 20° slew, 1 s after its start; written as
    ``directory/quick.toml``."""
    text = (SCENARIO_DIR / "cubesat-1u.toml").read_text()
    for old, new in (("duration_s = 35.0", "duration_s = 1.0"), ("warmup_s = 2.0", "warmup_s = 0.5"),
                     ("angle_deg = 90.0", "angle_deg = 20.0")):  # fmt: skip
        assert old in text
        text = text.replace(old, new)
    path = directory / "quick.toml"
    path.write_text(text)
    return path
