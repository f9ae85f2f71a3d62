"""The estimator on a recording a little beside the shared ones: a real phone trial with every sensor
silent for 3 s — a recording paused for less than a replay used to split at (10 s).

Found by a probe deriving variants of the shared real trials (other rates, gaps in one sensor or all,
duplicates, bursts, jitter, magnetic disturbances, clipping, saturation; ours against VQF on each): only
the pause of every sensor broke it. The one merged step across the pause had the gyro interpolated between
its two readings 3 s apart, inventing a rotation; the estimate came out ~60° tilted, the magnetometer was
then rejected as disturbed, and the heading stayed ~130° off for half a minute (a swung phone: 91° over the
20 s after the pause, VQF on the same steps 15°; BROAD 06: 124° against 26°). The live host never
integrated across such a pause — it starts its estimate afresh after 1 s without a reading — and a replay
now splits the log under the same rule (:data:`hil.estimation.sensors.MAX_PAUSE_S`).
"""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest

from hil.cli import replay as replay_cli
from hil.estimation.metrics import compare_to_truth
from hil.estimation.sensors import MAX_PAUSE_S
from hil.logs import read_log
from hil.logs.replay import MAX_GAP_S, ReplayOptions, replay
from hil.runtime import phone_clock
from hil.scenario.paths import SHARED_DATA

SWINGING = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_Dist_Swinging"
PAUSE_S = (64.0, 67.0)  # the trial's clock: the phone is being swung through it


def _paused(dst: Path, t0: float, t1: float) -> Path:
    """A copy of the trial's folder whose sensor files hold no reading stamped in ``[t0, t1]`` s (their first
    column), the motion capture's file as it is."""
    dst.mkdir()
    for f in SWINGING.iterdir():
        if not f.name.endswith(".txt.gz"):
            shutil.copy(f, dst / f.name)
            continue
        with gzip.open(f, "rt") as src, gzip.open(dst / f.name, "wt") as out:
            out.writelines(line for line in src if not t0 <= float(line.split(" ", 1)[0]) <= t1)
    return dst


def _rmse(folder: Path, t: np.ndarray, quat: np.ndarray, a: float, b: float) -> float:
    truth = read_log(folder).truth
    assert truth is not None
    c = compare_to_truth(truth.t, truth.R, truth.evaluate, t, quat)
    sel = c.mask & (c.t >= a) & (c.t <= b)
    assert sel.sum() > 500
    return float(np.sqrt(np.mean(c.errors.total[sel] ** 2)))


def test_a_pause_of_every_sensor_restarts_the_replay_s_estimate_and_invents_no_rotation(tmp_path):
    """After 3 s without any reading while the phone is swung, the replay's estimate starts afresh after the
    pause and is back within ~13° in the 20 s from 5 s after it (73° when integrated across) and within ~5°
    for the rest of the trial (18° before); the split is reported."""
    if not SWINGING.is_dir():
        pytest.skip(f"{SWINGING} not found")
    folder = _paused(tmp_path / SWINGING.name, *PAUSE_S)
    result = replay(folder, ReplayOptions(out_dir=tmp_path / "out"))
    est = result.estimates
    assert np.all(np.isfinite(est.quat))
    assert any("the filter restarts there" in w for w in result.warnings), result.warnings
    after = _rmse(folder, est.t, est.quat, PAUSE_S[1] + 5.0, PAUSE_S[1] + 25.0)
    rest = _rmse(folder, est.t, est.quat, PAUSE_S[1] + 23.0, np.inf)
    assert after < 25.0, after  # measured 13.2°; 72.8° integrated across the pause
    assert rest < 10.0, rest  # measured 5.1°; 18.2° before


def test_the_live_host_the_replay_and_its_command_line_restart_after_one_pause():
    """One rule for a pause of every sensor: the live host's phone clock, the replay's split and the
    command line's default (a literal there: the parser loads no estimator) are the same number."""
    assert phone_clock.MAX_GAP_S == MAX_GAP_S == replay_cli.MAX_GAP_S == MAX_PAUSE_S
