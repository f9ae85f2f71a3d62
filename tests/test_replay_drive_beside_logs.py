"""``hil replay LOG --port URL`` with logs just beside the ones the drive tests play: a log (or a
``--window``, or the longest part left between clock jumps) no longer than the warm-up, a log whose every
sensor pauses long enough to restart the warm-up near its end, NaN times, and a long log's memory.

Before: such a log drove the board through a warm-up that never ended and the run said ``completed``
(status 0) though the slew never started and the controller never held anything — the project's own
``honest_exit`` invariant names that a lie; and the recording kept one Python object per sample for the
whole log (~350 B each: ~360 MB more for an hour's three 100 Hz sensors) before the run began, sorted
by time: a clock that jumped back had its later stretch slipped in among the earlier one's samples.

Each drive runs against the in-process board in lockstep (fractions of a second), on CSV logs written
here in the project's own format (docs/formats.md).
"""

from __future__ import annotations

import json
import math
import tracemalloc
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.cli import main
from hil.estimation.sensors import KINDS, SensorLog, SensorStream
from hil.link.sources.recorded import RecordedSource, release_times
from hil.logs import read_log
from hil.runtime.phases import ROTOR_SETTLE_S

RATE_HZ = 50.0
WARMUP_S = 2.0  # cubesat-1u's
BOARD = "emu://?units=4&telemetry_rate=50"
QUICK = settings(max_examples=5, deadline=None)


def write_log(path: Path, spans: Sequence[tuple[float, float]]) -> Path:
    """A still phone (gravity on z, a constant field, small noise) sampled at :data:`RATE_HZ` by all three
    sensors over each ``(t0, t1)`` span (s), nothing between them: the project's CSV format."""
    rng = np.random.default_rng(7)
    lines = ["# vscmg-hil sensor log v1", "t_s,sensor,x,y,z,w"]
    for t0, t1 in spans:
        for t in np.arange(t0, t1, 1.0 / RATE_HZ):
            g = rng.normal(0.0, 1e-3, 3)
            a = rng.normal(0.0, 1e-2, 2)
            lines.append(f"{t:.6f},gyr,{g[0]:.6f},{g[1]:.6f},{g[2]:.6f},")
            lines.append(f"{t + 0.001:.6f},acc,{a[0]:.5f},{a[1]:.5f},9.81,")
            lines.append(f"{t + 0.002:.6f},mag,20.0,5.0,-40.0,")
    path.write_text("\n".join(lines) + "\n")
    return path


def _drive(tmp: Path, log: Path, *extra: str) -> tuple[int, Path]:
    out = tmp / f"runs-{log.stem}"
    return main(["replay", str(log), "--port", BOARD, "--out", str(out), "--no-plots", *extra]), out


@QUICK
@given(
    length=st.floats(0.5, WARMUP_S),
    cut=st.sampled_from(["log", "window", "gap"]),
)
def test_a_log_no_longer_than_the_warm_up_is_refused_before_a_board_is_armed(tmp_path_factory, length, cut):
    """Nothing to hold once warmed up: an error naming why (status 2), no run directory, no board armed —
    whether the log itself, a ``--window`` into the warm-up, or the longest part between clock jumps is
    that short."""
    tmp = tmp_path_factory.mktemp("short")
    extra: list[str] = []
    if cut == "log":
        log = write_log(tmp / "short.csv", [(0.0, length)])
    elif cut == "window":
        log = write_log(tmp / "long.csv", [(0.0, 8.0)])
        extra = ["--window", "3", f"{3.0 + length:.3f}"]
    else:  # two parts, each this short, 3 s apart (past the default --max-gap of 1 s)
        log = write_log(tmp / "gaps.csv", [(0.0, length), (length + 3.0, 2 * length + 3.0)])
    status, out = _drive(tmp, log, *extra)
    assert status == 2
    assert not out.exists() or not any(out.iterdir())  # refused before the run began


@QUICK
@given(
    pause_at=st.floats(1.0, 1.8),
    pause=st.floats(0.4, 0.9),  # past the host's phone-gap bound, within --max-gap (1 s): played, not split
    tail=st.floats(0.6, 1.7),  # less than a warm-up after the pause
)
def test_a_recording_that_ends_while_its_warm_up_restarts_is_not_completed(
    tmp_path_factory, pause_at, pause, tail
):
    """Every sensor pauses during the warm-up: the host restarts it (``warmup_restart``), and the log ends
    before the new one does. The run says so and is not ``completed`` (status 1, as for a run whose slew
    never started); the whole log was still played."""
    tmp = tmp_path_factory.mktemp("rewarm")
    resume = pause_at + pause
    # longer than the warm-up and the rotors' settling (shorter logs are refused before the run begins)
    least = WARMUP_S + ROTOR_SETTLE_S + 0.3
    log = write_log(tmp / "rewarm.csv", [(0.0, pause_at), (resume, max(resume + tail, least))])
    status, out = _drive(tmp, log)
    (run_dir,) = out.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    kinds = [json.loads(line)["kind"] for line in (run_dir / "events.jsonl").read_text().splitlines()]
    assert "warmup_restart" in kinds and "slew_start" not in kinds
    assert summary["exit"].startswith("incomplete: the recording ended before the slew started")
    assert status == 1
    assert summary["replay"]["samples_released"] == summary["phone_samples"]  # played to its end


def _log(streams: dict) -> SensorLog:
    return SensorLog({k: SensorStream(k, t, xyz) for k, (t, xyz) in streams.items()}, "drawn", "csv")


@settings(max_examples=40, deadline=None)
@given(
    data=st.data(),
    n=st.integers(2, 40),
    steps=st.lists(st.floats(0.001, 0.3), min_size=1, max_size=60),
)
def test_a_recording_releases_every_sample_once_in_each_sensors_recorded_order(data, n, steps):
    """Drawn streams (equal times across and within sensors, times that go back, NaN times the host drops)
    drained at drawn instants: every sample goes out exactly once, never before it is due, each sensor's in
    its recorded order (a sample whose time went back after the later ones, as a live phone sends it, for
    the host's admission to judge); the recording is exhausted once its end is due."""
    streams = {}
    for kind in KINDS:
        dt = data.draw(
            st.lists(st.sampled_from([-0.3, -0.01, 0.0, 0.01, 0.02, 0.05]), min_size=n, max_size=n)
        )
        t = 1.0 + np.cumsum(dt)
        nan = data.draw(st.lists(st.booleans(), min_size=n, max_size=n))
        t = np.where(np.array(nan) & (np.arange(n) > 0), math.nan, t)  # the first finite: a start
        streams[kind] = (t, np.arange(3 * n, dtype=float).reshape(n, 3) + 1000 * int(kind))
    log = _log(streams)
    source = RecordedSource(log, "recording://", 0.04, lambda *a, **k: None)
    origin = 10.0
    source.start(origin)
    shift = origin - log.start
    # when each sample is due, by sensor and value: its time — or, a stray stamped more than JUMP_S ahead
    # of the next finite sample (NaN times between), that sample's: it goes with it, as the phone sent it
    due = {
        (kind, x): r
        for kind, (t, xyz) in streams.items()
        for x, r in zip(xyz[:, 0].tolist(), release_times(t).tolist(), strict=True)
    }
    out, now = [], origin
    for step in steps + [log.end - log.start + 1e-9]:
        now += step
        batch = source.drain(now)
        assert all(due[(s.kind, s.xyz[0])] + shift <= now + 1e-9 for s in batch)  # none before it is due
        out += batch
    assert source.exhausted and source.released == 3 * n
    for kind, (t, xyz) in streams.items():
        mine = [s for s in out if s.kind == kind]
        assert [s.xyz[0] for s in mine] == xyz[:, 0].tolist()  # each once, in its recorded order
        np.testing.assert_array_equal([s.t_s for s in mine], t + shift)  # its own time, as recorded
    assert source.drain(now + 100.0) == []


@QUICK
@given(jump_at=st.floats(2.5, 4.0), back=st.floats(0.2, 0.6))
def test_a_log_whose_clock_jumps_back_is_not_interleaved_into_one_estimate(tmp_path_factory, jump_at, back):
    """Every sensor's clock jumps back by less than ``--max-gap`` (not split): what follows the jump is
    played after what preceded it, as a live phone would send it, and the host's merge drops what went back
    (as ``hil replay`` without ``--port`` does), or its admission restarts the phone's clock. It was sorted
    in among the earlier stretch's samples: the two stretches of motion interleaved into one estimate, an
    estimator step for every gyro sample of both."""
    tmp = tmp_path_factory.mktemp("back")
    resume = jump_at - back + 0.007  # its samples between the earlier stretch's, not on them
    log = write_log(tmp / "back.csv", [(0.0, jump_at), (resume, resume + 2.5)])
    status, out = _drive(tmp, log)
    (run_dir,) = out.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    gyr = read_log(log).streams[KINDS[0]].t
    forward = int(np.sum(gyr > np.maximum.accumulate(np.concatenate([[-np.inf], gyr[:-1]]))))
    restarted = summary["phone_admission"]["restarts"] > 0
    assert restarted or summary["estimator_steps"] <= forward + 2, (summary["estimator_steps"], forward)
    assert summary["replay"]["samples_released"] == summary["phone_samples"]  # played to its end
    assert status in (0, 1) and not summary["exit"].startswith(("lost", "error"))


def test_a_long_recording_costs_little_more_than_its_arrays():
    """An hour-long log's worth of samples (scaled down): the recording holds a few dozen bytes a sample
    while it waits to be played, not a Python object each (~350 B)."""
    n = 100_000  # per sensor
    t = np.arange(n) / 100.0
    streams = {k: (t + 0.001 * int(k), np.ones((n, 3))) for k in KINDS}
    log = _log(streams)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        source = RecordedSource(log, "recording://", 0.04, lambda *a, **k: None)
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert held / (3 * n) < 80, f"{held / (3 * n):.0f} B a sample"
    source.start(0.0)
    assert len(source.drain(1.0)) == 3 * 101  # played from the log's start (the mag's first, 0.002 s)
