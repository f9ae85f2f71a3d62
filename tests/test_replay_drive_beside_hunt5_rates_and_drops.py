"""``hil replay LOG --port URL`` with logs just beside the ones the drive tests play (a hunt's findings),
each through the real command against the in-process board in lockstep, on CSV logs written here in the
project's own format (docs/formats.md):

1. **A log slower than the control ticks' end margin** (below 25 Hz: a phyphox export at 20 Hz). The run
   ended two control ticks after the last sample was due, but the estimator task, at the log's own rate,
   drains it up to one of its periods later: the run, slewed and held, ended "time limit (the slew never
   started)", status 1, its recording never exhausted. It now runs until the last sample is drained.
2. **A log whose gyroscope or accelerometer samples further apart than the host's stale bound** (0.25 s:
   below 4 Hz). Every interval was a phone gap: the board was armed, its rotors spun up, and the run ended
   status 3 "lost: phone lost" for a recording that was never fast enough to steer on. It is now refused
   before a board is armed, saying why.
3. **A log the host's admission drops much of** (every row written several times, readings beyond a
   phone's range, a clock so far from zero — 1e15 s — that float64 seconds cannot tell its samples apart).
   The host drops those before its merge, so the merge's warnings (the batch replay's) saw none: two thirds
   of the log dropped and the run said "completed" without a word. It is now warned of, as the batch
   replay warns, printed and in ``summary.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hil.cli import main

BOARD = "emu://?units=4&telemetry_rate=50"
CAPTURED = [HealthCheck.function_scoped_fixture]  # capsys: read out at the start of each example


def write_log(
    path: Path,
    rate_hz: float,
    length_s: float,
    *,
    start_s: float = 0.0,
    lag_s: float = 0.0002,
    copies: int = 1,
    gyro_x: float = 0.0,
) -> Path:
    """A still phone (gravity on z, a constant field, small noise) whose three sensors sample at
    ``rate_hz`` over ``length_s`` from ``start_s`` (s), the accelerometer and magnetometer ``lag_s`` and
    twice that after the gyroscope, each row written ``copies`` times, ``gyro_x`` (rad/s) added to the
    gyroscope's x: the project's CSV format."""
    rng = np.random.default_rng(7)
    lines = ["# vscmg-hil sensor log v1", "t_s,sensor,x,y,z,w"]
    for t in start_s + np.arange(0.0, length_s, 1.0 / rate_hz):
        g = rng.normal(0.0, 1e-3, 3)
        a = rng.normal(0.0, 1e-2, 2)
        rows = [
            f"{t:.6f},gyr,{g[0] + gyro_x:.6f},{g[1]:.6f},{g[2]:.6f},",
            f"{t + lag_s:.6f},acc,{a[0]:.5f},{a[1]:.5f},9.81,",
            f"{t + 2 * lag_s:.6f},mag,20.0,5.0,-40.0,",
        ]
        for row in rows:
            lines += [row] * copies
    path.write_text("\n".join(lines) + "\n")
    return path


def _drive(log: Path, out: Path) -> int:
    return main(["replay", str(log), "--port", BOARD, "--out", str(out), "--no-plots"])


def _run(out: Path) -> tuple[dict, list[str]]:
    (run_dir,) = out.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    kinds = [json.loads(line)["kind"] for line in (run_dir / "events.jsonl").read_text().splitlines()]
    return summary, kinds


@settings(max_examples=8, deadline=None, suppress_health_check=CAPTURED)
@given(rate_hz=st.floats(4.5, 24.0), lag_s=st.floats(0.0, 0.01), length_s=st.floats(6.0, 9.0))
@example(rate_hz=20.0, lag_s=0.0002, length_s=8.0)  # ended "time limit (the slew never started)"
def test_a_slow_log_played_to_its_end_completes(tmp_path_factory, capsys, rate_hz, lag_s, length_s):
    """Any rate the host steers on (4-25 Hz, slower than two control ticks), any lag between the sensors,
    any length past the warm-up: the whole recording is played, the slew starts, the run completes."""
    capsys.readouterr()
    tmp = tmp_path_factory.mktemp("slow")
    log = write_log(tmp / "slow.csv", rate_hz, length_s, lag_s=lag_s)
    status = _drive(log, tmp / "runs")
    summary, kinds = _run(tmp / "runs")
    assert "slew_start" in kinds
    assert summary["exit"] == "completed", (summary["exit"], capsys.readouterr().err[-2000:])
    assert status == 0
    assert summary["replay"]["samples_released"] == summary["phone_samples"]  # played to its end


@settings(max_examples=4, deadline=None, suppress_health_check=CAPTURED)
@given(rate_hz=st.floats(0.5, 3.8), sensor=st.sampled_from(["gyroscope", "accelerometer"]))
def test_a_log_too_sparse_to_steer_on_is_refused_before_a_board_is_armed(
    tmp_path_factory, capsys, rate_hz, sensor
):
    """The gyroscope or the accelerometer (the other at 50 Hz) samples further apart than the host's stale
    bound: an error naming the sensor and why (status 2), no run directory, no board armed."""
    capsys.readouterr()
    tmp = tmp_path_factory.mktemp("sparse")
    fast = write_log(tmp / "fast.csv", 50.0, 12.0).read_text().splitlines()
    slow = write_log(tmp / "slow.csv", rate_hz, 12.0).read_text().splitlines()
    label = "gyr" if sensor == "gyroscope" else "acc"
    rows = [r for r in fast[2:] if f",{label}," not in r] + [r for r in slow[2:] if f",{label}," in r]
    rows.sort(key=lambda r: float(r.split(",")[0]))
    log = tmp / "mixed.csv"
    log.write_text("\n".join(fast[:2] + rows) + "\n")
    out = tmp / "runs"
    assert _drive(log, out) == 2
    err = capsys.readouterr().err
    assert f"the log's {sensor} samples every" in err and "stale" in err, err[-2000:]
    assert not out.exists() or not any(out.iterdir())  # refused before the run began


@settings(max_examples=6, deadline=None, suppress_health_check=CAPTURED)
@given(
    case=st.sampled_from(["copies", "beyond_range", "far_clock"]),
    copies=st.integers(2, 4),
)
def test_samples_the_host_drops_in_numbers_are_warned_of(tmp_path_factory, capsys, case, copies):
    """Most of a log dropped by the host's admission (its rows repeated, its gyroscope beyond a phone's
    range, its clock at 1e15 s): the run still ends as it ends, and it says how many samples it dropped
    and why, on stderr and in ``summary.json`` (``replay.warnings``), as the batch replay warns."""
    capsys.readouterr()
    tmp = tmp_path_factory.mktemp("drops")
    if case == "copies":
        log = write_log(tmp / "copies.csv", 50.0, 8.0, copies=copies)
        reason = "duplicate"
    elif case == "beyond_range":  # 50 rad/s: no phone's gyroscope measures it (±35 rad/s)
        fine = write_log(tmp / "fine.csv", 50.0, 8.0).read_text().splitlines()
        hot = write_log(tmp / "hot.csv", 50.0, 8.0, gyro_x=50.0).read_text().splitlines()
        keep = 2 + 3 * 150  # the first 3 s (the still window, the warm-up) as they were
        rows = fine[:keep] + [h if ",gyr," in h and i % copies == 0 else f for i, (f, h) in
                              enumerate(zip(fine[keep:], hot[keep:], strict=True))]  # fmt: skip
        log = tmp / "beyond.csv"
        log.write_text("\n".join(rows) + "\n")
        reason = "out of range"
    else:  # 50 Hz stamps at 1e15 s: float64 seconds step by 0.125 s there
        log = write_log(tmp / "far.csv", 50.0, 8.0, start_s=1e15)
        reason = "duplicate"
    _drive(log, tmp / "runs")
    summary, _ = _run(tmp / "runs")
    dropped = sum(summary["phone_admission"]["dropped"].values())
    assert dropped > 0.05 * summary["replay"]["samples_released"]
    err = capsys.readouterr().err
    said = [w for w in summary["replay"].get("warnings", []) if w.startswith("the host dropped")]
    assert len(said) == 1 and f"{dropped} of the recording's" in said[0] and reason in said[0], said
    assert f"warning: {said[0]}" in err
