"""``hil replay`` of exports just beside the ones it reads: a clock in Unix seconds, a tyrex NoDist trial,
phyphox exports paused and resumed, a sensor that stops under ``--port``, a folder of logs of several
formats, two copies of one sensor file, a sensor in a unit beyond its range, a stray row at 1e160 s.

Before: the estimates of an epoch clock were written to 10 s (hundreds of steps sharing one time);
NoDist_Phoning was scored without Dist_Phoning's excluded interval; a resumed phyphox export was placed
earlier by its pause; ``--port`` said "completed" of a magnetometer silent for three quarters of the run
where the batch replay warned; ``hil replay data/`` replayed one of the logs in it, exit 0; a second copy
of a sensor file was passed over without a word; a magnetometer in nT was blamed on the folder, a tyrex
gyroscope in ms on the magnetometer; and a row at 1e160 s printed numpy's overflow warning. Each log is
written here (the shared recordings read, never copied into the project).
"""

from __future__ import annotations

import gzip
import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from hil.cli import main
from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from hil.logs.gyro_units import gyro_turn_ratio
from hil.logs.replay import time_digits
from hil.logs.tyrex import excluded
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError
from tests.log_support import needs_real_export, real_export

TYREX = SHARED_DATA / "tyrex-nexus5"
needs_tyrex = pytest.mark.skipif(not TYREX.is_dir(), reason="the shared tyrex trials are not here")
BOARD = "emu://?units=4&telemetry_rate=50"


def write_csv(
    path: Path, t0: float, seconds: float, mag_until: float | None = None, rate: float = 50.0
) -> Path:
    """A still phone in the project's CSV (docs/formats.md) sampled at ``rate`` Hz from ``t0`` (s) for
    ``seconds``; its magnetometer only until ``t0 + mag_until`` when given."""
    rng = np.random.default_rng(3)
    lines = ["# vscmg-hil sensor log v1", "t_s,sensor,x,y,z,w"]
    for t in t0 + np.arange(0.0, seconds, 1.0 / rate):
        g, a = rng.normal(0.0, 1e-3, 3), rng.normal(0.0, 1e-2, 2)
        lines.append(f"{t:.6f},gyr,{g[0]:.6f},{g[1]:.6f},{g[2]:.6f},")
        lines.append(f"{t + 0.001:.6f},acc,{a[0]:.5f},{a[1]:.5f},9.81,")
        if mag_until is None or t < t0 + mag_until:
            lines.append(f"{t + 0.002:.6f},mag,20.0,5.0,-40.0,")
    path.write_text("\n".join(lines) + "\n")
    return path


def estimate_times(out: Path) -> tuple[np.ndarray, list[str]]:
    rows = (out / "estimates.csv").read_text().splitlines()[2:]
    return np.array([float(r.split(",")[0]) for r in rows]), [r.split(",")[0] for r in rows]


# 1 ---------------------------------------------------------------------------------------------------


def test_an_epoch_clock_keeps_every_step_time_in_estimates_csv(tmp_path):
    """``t_s`` in Unix seconds (1.7e9): every step keeps its own time, to the µs; 9 significant digits
    wrote them to 10 s."""
    log = write_csv(tmp_path / "epoch.csv", 1_714_550_400.0, 6.0)
    out = tmp_path / "out"
    assert main(["replay", str(log), "--out", str(out), "--no-plots"]) == 0
    t, _ = estimate_times(out)
    assert len(np.unique(t)) == len(t)
    assert np.allclose(np.diff(t), 0.02, atol=2e-6)
    assert t[0] == pytest.approx(1_714_550_400.0, abs=0.05)


def test_a_clock_from_its_start_writes_its_times_as_before(tmp_path):
    """A log on a clock from its start (below 1000 s) is written with the 9 digits it always was."""
    assert time_digits(np.array([0.0, 999.9])) == 9
    assert time_digits(np.array([1.7e9])) == 16
    assert time_digits(np.array([np.nan, 1e160])) == 17
    log = write_csv(tmp_path / "small.csv", 0.0, 6.0)
    out = tmp_path / "out"
    assert main(["replay", str(log), "--out", str(out), "--no-plots"]) == 0
    t, cells = estimate_times(out)
    assert cells == [f"{x:.9g}" for x in t]


# 2 ---------------------------------------------------------------------------------------------------


def test_tyrex_exclusions_match_the_trial_condition_exactly():
    assert excluded("Guillaume_Nexus5_Dist_Phoning") == ((40.5, 40.8),)
    assert excluded("Guillaume_Nexus5_NoDist_Phoning") == ()
    assert excluded("Guillaume_Nexus5_NoDist_FrontPocket") == ()
    assert excluded("Guillaume_Nexus5_NoDist_Swinging") == ()
    assert excluded("Guillaume_Nexus5_NoDist_AR") == ((64.0, 120.0),)
    assert excluded("Guillaume_Nexus5_Dist_AR") == ()
    assert excluded("Dist_Swinging") == ((59.7, 60.5), (73.1, 73.5))


@needs_tyrex
def test_a_nodist_trial_is_scored_without_the_dist_trials_intervals():
    """NoDist_FrontPocket, _Phoning and _Swinging: no interval excluded, every motion-capture frame in
    their Dist namesakes' intervals that is not occluded is scored (FrontPocket's and Swinging's were not)."""
    scored = 0
    for condition in ("FrontPocket", "Phoning", "Swinging"):
        nodist = read_log(TYREX / f"Guillaume_Nexus5_NoDist_{condition}")
        assert not [n for n in nodist.notes if "excluded" in n]
        truth = nodist.truth
        assert truth is not None and truth.evaluate is not None
        t_mocap = np.arange(len(truth.t)) / 60.0
        seen = np.all(np.isfinite(truth.R), axis=(1, 2))
        for a, b in excluded(f"Guillaume_Nexus5_Dist_{condition}"):
            inside = (t_mocap >= a) & (t_mocap <= b) & seen
            assert truth.evaluate[inside].all()
            scored += int(inside.sum())
    assert scored > 0
    dist = read_log(TYREX / "Guillaume_Nexus5_Dist_Phoning")
    assert [n for n in dist.notes if "excluded" in n]


# 3 ---------------------------------------------------------------------------------------------------

START_S = 1_714_550_400.0


def phyphox_export(folder: Path, head: list[str], t: np.ndarray, xyz, events) -> None:
    """A built-in phyphox single-sensor export: ``Raw Data.csv`` and ``meta/time.csv`` with ``events``
    (event, experiment time, system time)."""
    (folder / "meta").mkdir(parents=True)
    rows = [",".join(f'"{h}"' for h in head)]
    rows += [",".join(f"{v:.9E}" for v in (tt, *xyz(tt))) for tt in t]
    (folder / "Raw Data.csv").write_text("\n".join(rows) + "\n")
    lines = ['"event","experiment time","system time","system time text"']
    lines += [f'"{ev}",{et:.9E},{st:.3f},"x"' for ev, et, st in events]
    (folder / "meta" / "time.csv").write_text("\n".join(lines) + "\n")


def paused_exports(root: Path, acc_events) -> Path:
    """A gyroscope recorded 0-70 s unpaused, and an accelerometer with ``acc_events``."""
    gyr_head = ["Time (s)", "Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)"]
    phyphox_export(
        root / "Gyroscope",
        gyr_head,
        np.arange(0, 70, 0.01),
        lambda tt: (0.0, 0.0, 0.0),
        [("START", 0.0, START_S), ("PAUSE", 70.0, START_S + 70)],
    )
    acc_head = ["Time (s)", "Acceleration x (m/s^2)", "Acceleration y (m/s^2)", "Acceleration z (m/s^2)"]
    phyphox_export(
        root / "Acceleration with g",
        acc_head,
        np.arange(0, 40, 0.01),
        lambda tt: (0.0, 0.0, 9.81),
        acc_events,
    )
    return root


def test_a_phyphox_export_paused_and_resumed_has_each_stretch_placed_by_its_start(tmp_path):
    """The accelerometer recorded 0-20 s, paused 30 s, resumed (experiment time 20-40 s, wall 50-70 s):
    its samples after the resume lie 30 s later than their experiment time, beside the gyroscope's of
    the same moment; the pause is noted."""
    root = paused_exports(
        tmp_path / "exports",
        [
            ("START", 0.0, START_S),
            ("PAUSE", 20.0, START_S + 20),
            ("START", 20.0, START_S + 50),
            ("PAUSE", 40.0, START_S + 70),
        ],
    )
    log = read_log(root)
    acc = log.streams[SensorKind.ACC].t
    assert acc[np.searchsorted(np.arange(0, 40, 0.01), 25.0)] == pytest.approx(55.0)
    assert acc[:2000].max() < 20.0 and acc[2000:].min() >= 50.0
    assert any("paused and resumed 1 time(s)" in n and "for 30.000 s" in n for n in log.notes)


def test_a_phyphox_resume_before_its_pause_is_an_error_naming_time_csv(tmp_path):
    root = paused_exports(
        tmp_path / "exports",
        [("START", 0.0, START_S), ("PAUSE", 20.0, START_S + 20), ("START", 20.0, START_S + 10)],
    )
    with pytest.raises(InputFormatError, match="before the one before it") as err:
        read_log(root)
    assert "Acceleration with g/meta/time.csv" in str(err.value)


# 4 ---------------------------------------------------------------------------------------------------


def test_a_drive_whose_magnetometer_stops_warns_as_the_batch_replay_does(tmp_path, capsys):
    """``--port`` with a magnetometer silent after a quarter of the log: the run's merge counters give the
    batch replay's warning, printed and in ``summary.json`` (``replay.warnings``)."""
    log = write_csv(tmp_path / "magstops.csv", 0.0, 12.0, mag_until=3.0)
    out = tmp_path / "runs"
    status = main(["replay", str(log), "--port", BOARD, "--out", str(out), "--no-plots"])
    err = capsys.readouterr().err
    (run_dir,) = out.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert status == 0 and summary["exit"] == "completed"
    stale = [w for w in summary["replay"]["warnings"] if w.startswith("mag: stale")]
    assert stale and f"warning: {stale[0]}" in err
    batch = tmp_path / "batch"
    assert main(["replay", str(log), "--out", str(batch), "--no-plots"]) == 0
    said = json.loads((batch / "summary.json").read_text())["warnings"]
    assert any(w.startswith("mag: stale") for w in said)


# 5 ---------------------------------------------------------------------------------------------------


@needs_real_export
def test_a_folder_of_logs_of_different_formats_is_refused_listing_them(tmp_path, capsys):
    root = tmp_path / "data"
    real_export(root / "phone")
    write_csv((root / "bench").mkdir(parents=True) or root / "bench" / "log.csv", 0.0, 4.0)
    assert main(["replay", str(root), "--out", str(tmp_path / "out"), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "it holds logs: replay one" in err
    assert (
        "csv: " in err
        and str(root / "bench") in err
        and "sensorlogger: " in err
        and str(root / "phone") in err
    )
    assert not (tmp_path / "out").exists()


@needs_real_export
def test_a_folder_holding_one_export_below_it_still_replays(tmp_path):
    root = tmp_path / "data"
    real_export(root / "phone")
    (root / "README.txt").write_text("my recording\n")
    assert read_log(root).format == "sensorlogger"


# 6 ---------------------------------------------------------------------------------------------------


@needs_real_export
def test_two_different_copies_of_a_sensor_logger_file_are_refused_naming_both(tmp_path):
    folder = real_export(tmp_path / "rec")
    text = (folder / "Gyroscope.csv").read_text().splitlines()
    (folder / "Gyroscope.csv.gz").write_bytes(gzip.compress(("\n".join(text[:100]) + "\n").encode()))
    with pytest.raises(InputFormatError, match="another copy of") as err:
        read_log(folder)
    assert "Gyroscope.csv.gz" in str(err.value) and str(folder / "Gyroscope.csv") in str(err.value)


@needs_real_export
def test_two_identical_copies_of_a_sensor_logger_file_are_read_once_and_noted(tmp_path):
    folder = real_export(tmp_path / "rec")
    (folder / "Gyroscope.csv.gz").write_bytes(gzip.compress((folder / "Gyroscope.csv").read_bytes()))
    reference = read_log(real_export(tmp_path / "plain"))
    log = read_log(folder)
    assert len(log.streams[SensorKind.GYR]) == len(reference.streams[SensorKind.GYR])
    assert any("Gyroscope.csv.gz: the same bytes as Gyroscope.csv" in n for n in log.notes)


def tyrex_trial(folder: Path, rate: float = 100.0, seconds: float = 6.0, time_scale: float = 1.0) -> Path:
    """A small tyrex trial (no truth): the three calibrated files, plain text; a still phone."""
    folder.mkdir(parents=True)
    t = np.arange(0.0, seconds, 1.0 / rate) * time_scale
    for name, xyz in (
        ("accelerometer.txt", (0.0, 0.0, 9.81)),
        ("gyroscope-calibrated.txt", (0.001, -0.002, 0.0)),
        ("magnetometer-calibrated.txt", (20.0, 5.0, -40.0)),
    ):
        (folder / name).write_text("".join(f"{tt:.6f} {xyz[0]} {xyz[1]} {xyz[2]}\n" for tt in t))
    return folder


def test_two_copies_of_a_tyrex_file_are_read_once_when_the_same_and_refused_when_not(tmp_path):
    same = tyrex_trial(tmp_path / "same")
    data = (same / "gyroscope-calibrated.txt").read_bytes()
    (same / "gyroscope-calibrated.txt.gz").write_bytes(gzip.compress(data))
    log = read_log(same)
    assert log.format == "tyrex"
    assert any(
        "gyroscope-calibrated.txt: the same bytes as gyroscope-calibrated.txt.gz" in n for n in log.notes
    )
    other = tyrex_trial(tmp_path / "other")
    (other / "gyroscope-calibrated.txt.gz").write_bytes(gzip.compress(data[: len(data) // 4]))
    with pytest.raises(InputFormatError, match="another copy of") as err:
        read_log(other)
    assert "gyroscope-calibrated.txt.gz" in str(err.value) and "gyroscope-calibrated.txt:" in str(err.value)


# 7 ---------------------------------------------------------------------------------------------------


@needs_real_export
def test_a_magnetometer_in_nt_is_an_error_naming_its_file_and_the_unit(tmp_path, capsys):
    def in_nt(name: str, lines: list[str]) -> list[str]:
        if name != "Magnetometer.csv":
            return lines
        return [lines[0]] + [
            ",".join(cells[:2] + [repr(float(v) * 1000) for v in cells[2:]])
            for cells in (line.split(",") for line in lines[1:])
        ]

    folder = real_export(tmp_path / "rec", in_nt)
    assert main(["replay", str(folder), "--out", str(tmp_path / "out"), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert str(folder / "Magnetometer.csv") in err and "nT" in err and "every MAG reading" in err


def test_a_tyrex_file_with_times_in_ms_is_an_error_naming_it_and_its_time_column(tmp_path):
    trial = tyrex_trial(tmp_path / "trial")
    (trial / "gyroscope-calibrated.txt").unlink()
    tyrex_trial(tmp_path / "ms", time_scale=1000.0)
    shutil.copy(tmp_path / "ms" / "gyroscope-calibrated.txt", trial / "gyroscope-calibrated.txt")
    with pytest.raises(InputFormatError, match="median 10 s apart") as err:
        read_log(trial)
    assert "gyroscope-calibrated.txt" in str(err.value) and "col0" in str(err.value)


# 8 ---------------------------------------------------------------------------------------------------


@needs_tyrex
@pytest.mark.parametrize("stray", ["1e160", "1e308"])
def test_a_tyrex_row_far_in_the_future_makes_no_overflow(tmp_path, stray):
    """A gyroscope row at 1e160 s in the middle of a real trial: the unit check integrates over the
    samples in time order (it interpolated over a clock that went back) with no numpy warning; its ratio
    is the trial's own."""
    source = TYREX / "Guillaume_Nexus5_NoDist_Texting"
    trial = tmp_path / source.name
    shutil.copytree(source, trial)
    lines = gzip.decompress((trial / "gyroscope-calibrated.txt.gz").read_bytes()).decode().splitlines()
    cells = lines[1000].split()
    lines[1000] = " ".join([stray, *cells[1:]])
    (trial / "gyroscope-calibrated.txt.gz").write_bytes(gzip.compress(("\n".join(lines) + "\n").encode()))
    reference = gyro_turn_ratio(read_log(source))
    log = read_log(trial)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        ratio, windows = gyro_turn_ratio(log)
    assert ratio == pytest.approx(reference[0], rel=0.05) and windows >= reference[1] - 2
