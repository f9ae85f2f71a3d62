"""A gyroscope or accelerometer pinned at one large value for a stretch — clipped at its range — is said:
the replay's warnings (stdout and ``summary.json``) name the sensor, how many samples and where. Before, a
gyroscope pinned at 8.73 rad/s for 2 s was integrated as a turn of 17.5 rad without a word. Through the
real Sensor Logger export cut short, with drawn runs of pinned readings written into its file."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind
from hil.logs.replay import PINNED_FLOOR, PINNED_RUN, ReplayOptions, replay
from tests.log_support import needs_real_export, real_export

REPO = Path(__file__).resolve().parents[1]
FILES = {SensorKind.GYR: "Gyroscope.csv", SensorKind.ACC: "TotalAcceleration.csv"}


def _pin(folder: Path, kind: SensorKind, first: int, count: int, value: float, column: int) -> Path:
    """The real export in ``folder``, ``kind``'s rows ``first`` .. ``first + count - 1`` reading ``value``
    in ``column`` (2, 3, 4: z, y, x)."""

    def edit(name: str, lines: list[str]) -> list[str]:
        if name != FILES[kind]:
            return lines
        out = list(lines)
        for row in range(first, first + count):
            cells = out[row].split(",")
            cells[column] = repr(value)
            out[row] = ",".join(cells)
        return out

    return real_export(folder, edit)


@needs_real_export
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    kind=st.sampled_from(list(FILES)),
    first=st.integers(20, 300),
    count=st.integers(2, 60),
    scale=st.floats(1.0, 3.0),
    sign=st.sampled_from([-1.0, 1.0]),
    column=st.sampled_from([2, 3, 4]),
)
def test_a_sensor_pinned_at_a_large_value_is_said(tmp_path_factory, kind, first, count, scale, sign, column):
    root = tmp_path_factory.mktemp("pinned")
    value = sign * PINNED_FLOOR[kind] * scale
    log = _pin(root / "log", kind, first, count, value, column)
    result = replay(log, ReplayOptions(out_dir=root / "out"))
    said = [w for w in result.warnings if "pinned at one value" in w]
    summary = json.loads((root / "out" / "summary.json").read_text())
    if count >= PINNED_RUN:
        assert len(said) == 1 and said[0].startswith(f"{kind.label}: {count} samples"), result.warnings
        assert said[0] in summary["warnings"]
    else:  # a few equal samples: no clipping told apart from chance
        assert not said, said
    quat = result.estimates.quat
    assert abs((quat**2).sum(axis=1) - 1).max() < 1e-6


@needs_real_export
def test_the_unchanged_export_says_nothing_pinned_and_the_cli_says_it(tmp_path):
    plain = replay(real_export(tmp_path / "plain"), ReplayOptions(out_dir=tmp_path / "o1"))
    assert not [w for w in plain.warnings if "pinned" in w]
    log = _pin(tmp_path / "log", SensorKind.GYR, 100, 99, 8.73, 4)
    run = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(log), "--no-plots", "--out", str(tmp_path / "o2")],
        capture_output=True, text=True, timeout=300, cwd=REPO,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    assert "warning: gyr: 99 samples pinned at one value, up to 8.73 rad/s" in run.stdout, run.stdout
