"""VQF integrates every merged step through its real length, not one fixed period: a log with gaps shorter
than a replay's ``max_gap_s`` (a recording that hiccuped for 0.6 s), or a gyroscope whose rate dropped
part-way, turned the attitude through one nominal period for each such step — a 0.8 s gap at 200 Hz was
integrated as 5 ms, silently. Drawn gaps against a constant rotation (the property), and the real TyREx
recording with a gap cut out of it, replayed through ``hil replay --estimator vqf`` against its ground truth.
"""

from __future__ import annotations

import gzip
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("vqf")

from hil.estimation.interface import Site  # noqa: E402
from hil.estimation.sensors import MergedSteps  # noqa: E402
from hil.estimation.slots import MAX_SUBSTEPS  # noqa: E402
from hil.estimation.vqf_adapter import VQF_ESTIMATOR, gyro_updates  # noqa: E402
from hil.scenario.paths import SHARED_DATA  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PERIOD_S = 0.005
RATE = 0.7  # rad/s about the vertical: gravity stays put, the yaw is the gyroscope's integral alone
FIXED = {"motion_bias": False, "rest_bias": False}  # no bias learnt from a rotation held constant


def _steps(t: np.ndarray) -> MergedSteps:
    n = len(t)
    gyr = np.tile([0.0, 0.0, RATE], (n, 1))
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    return MergedSteps(
        t, gyr, acc, np.full((n, 3), np.nan), np.zeros((n, 3)), np.ones((n, 3), bool), np.zeros(n, np.int64)
    )


def _yaw(r: np.ndarray) -> float:
    return math.atan2(r[1, 0], r[0, 0])


def _wrapped(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


@settings(max_examples=40, deadline=None)
@given(
    gaps=st.lists(
        st.tuples(st.integers(5, 380), st.floats(1.6, 150.0)),
        min_size=1,
        max_size=4,
        unique_by=lambda g: g[0],
    ),
    live=st.booleans(),
)
def test_the_attitude_turns_through_each_steps_real_time(gaps, live):
    h = np.full(400, PERIOD_S)
    for at, periods in gaps:  # a step that spans this many periods: the sensors silent before it
        h[at] = periods * PERIOD_S
    t = 10.0 + np.cumsum(h)
    site = Site.of_dip(60.0, 0.0, PERIOD_S, magnetometer=False)
    est = VQF_ESTIMATOR.build(VQF_ESTIMATOR.check(FIXED, "t"), site)
    steps = _steps(t)
    if live:
        last = [est.step(steps[i]) for i in range(len(t))][-1].R
    else:
        out = est.run(steps)
        last = out.R[-1]
        assert np.isfinite(out.R).all()
    expected = RATE * (t[-1] - t[0] + PERIOD_S)  # the first step integrates one period too
    tolerance = RATE * PERIOD_S * (0.5 * len(gaps) + 0.01)  # each long step to within half a period
    assert abs(_wrapped(_yaw(last) - expected)) <= tolerance, (_yaw(last), expected % (2 * math.pi))


def test_an_on_time_step_is_one_update_and_a_paused_recording_is_refused():
    assert gyro_updates(None, PERIOD_S) == 1
    assert gyro_updates(PERIOD_S * 1.4, PERIOD_S) == 1  # phone jitter
    assert gyro_updates(PERIOD_S * 0.2, PERIOD_S) == 1  # a burst
    assert gyro_updates(0.8, PERIOD_S) == 160
    with pytest.raises(ValueError, match="split the log at the gap"):
        gyro_updates(PERIOD_S * (MAX_SUBSTEPS + 1), PERIOD_S)


TRIAL = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_NoDist_Swinging"
THROTTLED = ("gyroscope-calibrated.txt.gz", "accelerometer.txt.gz")


def _throttled(src: Path, dst: Path, after_s: float, every: int) -> None:
    """``src``'s trial in ``dst``, its gyroscope and accelerometer keeping one sample in ``every`` from
    ``after_s`` (s) on: a phone that throttled its sensors (the app sent to the background)."""
    dst.mkdir()
    t0 = float(np.loadtxt(src / THROTTLED[0])[0, 0])
    for f in src.iterdir():
        if f.name in THROTTLED:
            a = np.loadtxt(f)
            keep = (a[:, 0] < t0 + after_s) | (np.arange(len(a)) % every == 0)
            with gzip.open(dst / f.name, "wt") as out:
                np.savetxt(out, a[keep], fmt="%.9g")
        elif not f.name.endswith(".txt.gz") or f.name == "magnetometer-calibrated.txt.gz":
            shutil.copy(f, dst / f.name)


@pytest.mark.skipif(not TRIAL.is_dir(), reason="the shared TyREx recording is not here")
def test_a_real_recording_whose_rate_drops_is_estimated_through_its_real_time(tmp_path):
    slow = tmp_path / "slow"
    _throttled(TRIAL, slow, 60.0, 4)  # 199 Hz, then ~50 Hz: every step after 60 s spans 4 periods
    run = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(slow), "--estimator", "vqf", "--no-plots",
         "--out", str(tmp_path / "out")],
        capture_output=True, text=True, timeout=600, cwd=REPO, env={**os.environ},
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["rate_drops"], summary["warnings"]  # said
    assert "nominal rate" not in " ".join(summary["warnings"])  # no longer what VQF does
    assert summary["flagged_steps"]["SUBSTEPPED"] > 1000, summary["flagged_steps"]
    # the whole trial scores ~3.9 deg; before, each slow step turned the attitude a quarter of its way: 73 deg
    assert summary["rmse_deg"]["total"] < 8.0, summary["rmse_deg"]
