"""``hil replay LOG --port URL`` with logs whose edges are beside the tested path (a hunt's findings), each
through the real command against the in-process board in lockstep:

1. **A log whose gyroscope ends before its accelerometer** (the shipped Sensor Logger export: the gyroscope
   at 700.88 s, the accelerometer at 701.65 s). The run played on to the last sample of any sensor, and
   the gyroscope simply ending was a phone lost: "lost: phone lost … no gyroscope reading came", status 3,
   for a recording replayed to its end. The board is now driven until both sensors the host steers with
   have spoken for the last time, and said so.
2. **A recording restarted** (its clock from zero again, a second stretch appended). The second stretch,
   stamped over the first one's times, was released all at once behind it: phone restarts and jumps, and
   "completed" for a run driven by the first stretch alone, without a word. The board is now driven with
   the stretch before the restart, and the operator told.
3. **A log too short to reach the slew** (the warm-up and the rotors' settling: 3 s for cubesat-1u) is
   refused before a board is armed; a 2.5 s log armed and spun the rotors, then ended "incomplete".
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream
from hil.logs.replay import TRIM_S, before_clock_restart, steerable_end

ROOT = Path(__file__).resolve().parents[1]
SENSORLOGGER = ROOT.parent / "shared" / "data" / "sensorlogger-android"
RATE_HZ = 50.0


def _drive(log: Path | str, out: Path, *extra: str) -> tuple[subprocess.CompletedProcess[str], dict]:
    argv = ["replay", str(log), "--port", "emu://?units=4", "--no-plots", "--out", str(out), *extra]
    done = subprocess.run([sys.executable, "-m", "hil", *argv], capture_output=True, text=True, timeout=300)
    summaries = list(out.glob("*/summary.json"))
    return done, (json.loads(summaries[0].read_text()) if summaries else {})


def _write_csv(path: Path, spans: list[tuple[float, float]], gyr_ends_early_s: float = 0.0) -> Path:
    """A project CSV of a still phone at 50 Hz over ``spans`` played in order (the clock may go back)."""
    rng = np.random.default_rng(7)
    lines = ["# vscmg-hil sensor log v1", "t_s,sensor,x,y,z,w"]
    last = spans[-1][1]
    for t0, t1 in spans:
        for t in np.arange(t0, t1, 1.0 / RATE_HZ):
            g, a = rng.normal(0.0, 1e-3, 3), rng.normal(0.0, 1e-2, 2)
            if not (gyr_ends_early_s and t > last - gyr_ends_early_s):
                lines.append(f"{t:.6f},gyr,{g[0]:.6f},{g[1]:.6f},{g[2]:.6f},")
            lines.append(f"{t + 0.001:.6f},acc,{a[0]:.5f},{a[1]:.5f},9.81,")
            lines.append(f"{t + 0.002:.6f},mag,20.0,5.0,-40.0,")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.skipif(not SENSORLOGGER.is_dir(), reason="../shared/data is not present")
def test_a_recording_replayed_to_its_end_completes(tmp_path):
    done, summary = _drive(SENSORLOGGER, tmp_path / "runs", "--window", "690", "720")
    assert done.returncode == 0, (done.stdout[-2000:], done.stderr[-2000:])
    assert summary["exit"] == "completed" and summary["phone_gaps"] == 0
    assert "where the log's gyroscope ends" in done.stderr


def test_a_log_whose_gyroscope_ends_first_is_driven_to_its_end(tmp_path):
    log = _write_csv(tmp_path / "gyr_first.csv", [(0.0, 8.0)], gyr_ends_early_s=0.8)
    done, summary = _drive(log, tmp_path / "runs")
    assert done.returncode == 0, done.stderr[-2000:]
    assert summary["exit"] == "completed" and summary["phone_gaps"] == 0


def test_a_restarted_recording_drives_the_stretch_before_its_restart_and_says_so(tmp_path):
    log = _write_csv(tmp_path / "restart.csv", [(0.0, 8.0), (0.0, 8.0)])
    done, summary = _drive(log, tmp_path / "runs")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "clock goes back" in done.stderr and "after it left out" in done.stderr
    assert summary["exit"] == "completed" and summary["phone_restarts"] == 0
    assert summary["phone_admission"]["jumps"] == 0 and summary["phone_admission"]["restarts"] == 0


def test_a_log_too_short_to_reach_the_slew_is_refused_before_a_board_is_armed(tmp_path):
    log = _write_csv(tmp_path / "short.csv", [(0.0, 2.5)])
    done, summary = _drive(log, tmp_path / "runs")
    assert done.returncode == 2 and not summary
    assert "warm-up and the rotors' settling" in done.stderr


@settings(max_examples=60, deadline=None)
@given(
    ends=st.tuples(st.floats(1.1, 20.0), st.floats(1.1, 20.0), st.floats(1.1, 20.0)),
    restart=st.booleans(),
)
def test_what_is_driven_ends_where_both_steering_sensors_have_spoken_and_never_goes_back(ends, restart):
    """Any three ends, any restart: what is left goes on at most ``TRIM_S`` (shorter than a phone gap)
    past the last time both the gyroscope and the accelerometer speak, every stream's times in order."""
    streams = {}
    for kind, end in zip((SensorKind.GYR, SensorKind.ACC, SensorKind.MAG), ends, strict=True):
        t = np.arange(0.0, end, 0.02)
        if restart:
            t = np.concatenate([t, t])  # the recording again, its clock from zero: back by over 1 s
        streams[kind] = SensorStream(kind, t, np.zeros((len(t), 3)))
    log = SensorLog(streams, "drawn", "csv")
    kept, said = before_clock_restart(log, max_gap_s=1.0)
    assert (said is not None) is restart
    kept, _ = steerable_end(kept)
    gyr_end = kept.streams[SensorKind.GYR].t.max()
    acc_end = kept.streams[SensorKind.ACC].t.max()
    both_end = min(gyr_end, acc_end)  # past it, a tail of at most TRIM_S (shorter than a gap) is kept
    assert max(gyr_end, acc_end, kept.streams[SensorKind.MAG].t.max()) <= both_end + TRIM_S + 1e-9
    for stream in kept.streams.values():
        assert np.all(np.diff(stream.t) > 0)
