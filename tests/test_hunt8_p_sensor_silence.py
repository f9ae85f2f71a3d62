"""One sensor falling silent for a stretch while the others go on sampling is said, with where and how long.

The log's clock does not jump there (every sensor's times together), so the replay does not split it: the
filter runs on through the silence on the other sensors, its steps flagged stale. The merge's stale count
was the only trace and is warned about only beyond 5 % of the steps: the gyroscope cut out of a real BROAD
trial (06, fast rotation) for 5 s of its 200 s — 2.4 % — left the estimates 89° off in motion (VQF's
81° off: no estimator tracks a turn without a rate) with not a word in the replay's warnings or
summary. Drawn: which sensor, where in the motion, and for how long (under the 5 % that was warned).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream, Truth
from hil.logs import project_csv, read_log
from hil.logs.replay import ReplayOptions, replay
from hil.scenario.paths import SHARED_DATA

TRIAL = SHARED_DATA / "broad" / "06_undisturbed_fast_rotation_A.mat"
WINDOW_S = (40.0, 70.0)  # in its motion (BROAD's 'movement' 37.6-160.2 s); 8,570 steps
pytestmark = pytest.mark.skipif(not TRIAL.is_file(), reason="the shared BROAD trial is not here")


def _window() -> SensorLog:
    log = read_log(TRIAL).window(*WINDOW_S)
    truth = log.truth
    assert truth is not None
    keep = np.all(np.isfinite(truth.R.reshape(len(truth.t), 9)), axis=1)
    return SensorLog(dict(log.streams), log.source, log.format, Truth(truth.t[keep], truth.R[keep]))


def _silenced(log: SensorLog, kind: SensorKind, t0: float, t1: float) -> SensorLog:
    streams = dict(log.streams)
    s = streams[kind]
    keep = (s.t < t0) | (s.t > t1)
    streams[kind] = SensorStream(kind, s.t[keep], s.xyz[keep])
    return SensorLog(streams, log.source, log.format, log.truth)


def _paused(log: SensorLog, t0: float, t1: float) -> SensorLog:
    """Every sensor silent over (t0, t1): a pause of the whole log, shorter than a gap."""
    streams = {}
    for kind, s in log.streams.items():
        keep = (s.t < t0) | (s.t > t1)
        streams[kind] = SensorStream(kind, s.t[keep], s.xyz[keep])
    return SensorLog(streams, log.source, log.format, log.truth)


def _replay(log: SensorLog, folder: Path) -> tuple[list[str], dict]:
    folder.mkdir(parents=True, exist_ok=True)
    path = project_csv.write(log, folder / "log.csv")
    result = replay(path, ReplayOptions(out_dir=folder / "out"))
    summary = json.loads((folder / "out" / "summary.json").read_text(encoding="utf-8"))
    assert summary["warnings"] == result.warnings
    return result.warnings, summary


@settings(
    max_examples=4,
    deadline=None,
    phases=(Phase.explicit, Phase.reuse, Phase.generate),  # a replay takes seconds: no shrinking
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    kind=st.sampled_from([SensorKind.GYR, SensorKind.ACC, SensorKind.MAG]),
    start=st.floats(45.0, 65.0),
    length=st.floats(0.4, 1.4),  # under 5 % of the 30 s (the stale count's warning) and under a gap
)
def test_a_sensor_silent_while_the_others_go_on_is_said(
    tmp_path_factory: pytest.TempPathFactory, kind: SensorKind, start: float, length: float
) -> None:
    log = _silenced(_window(), kind, start, start + length)
    warnings, summary = _replay(log, tmp_path_factory.mktemp("silence"))
    said = [w for w in warnings if w.startswith(f"{kind.label}: silent for ")]
    assert len(said) == 1, warnings
    began, ended = (float(x) for x in re.search(r"\(([-\d.]+)-([-\d.]+) s\)", said[0]).groups())
    assert abs(began - start) < 0.01 and abs(ended - (start + length)) < 0.01, said[0]  # where, how long
    assert summary["segments"] == [s for s in summary["segments"] if "skipped" not in s]  # not split


def test_the_whole_log_pausing_is_no_one_sensors_silence(tmp_path: Path) -> None:
    log = _paused(_window(), 50.0, 50.6)  # shorter than a gap (1 s): not split; no sensor alone silent
    warnings, _ = _replay(log, tmp_path)
    assert not [w for w in warnings if "silent for" in w], warnings


def test_the_trial_as_recorded_has_no_silence(tmp_path: Path) -> None:
    warnings, _ = _replay(_window(), tmp_path)
    assert not [w for w in warnings if "silent for" in w], warnings
