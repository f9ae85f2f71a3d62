"""The runtime end to end: scenarios, the lockstep closed loop through the full protocol and board, a link
fault → FAILSAFE → re-arm, real time over a real pty against a separate firmware-sim with its world and
phone stream, and a killed run's log."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from firmware_sim.world import World
from hil.estimation.registry import EstimatorChoice
from hil.runtime import RunOptions, run, telemetry_columns
from hil.runtime.runlog import read_events, read_telemetry
from hil.scenario import load_scenario, parse_scenario, scenario_names
from hil.version import package_version
from protocol.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def _quick(name: str = "cubesat-1u"):
    """A shipped scenario with a 30° slew about its axis (keeps the tests short; a slew much faster than
    0.15 rad/s outruns the paper's 1 rad/s pre-filter and the estimate lags by degrees)."""
    from hil import so3

    sc = load_scenario(name)
    axis = so3.log(sc.slew.R0.T @ sc.slew.R_target)
    target = sc.slew.R0 @ so3.exp(axis / np.linalg.norm(axis) * np.radians(30.0))
    slew = sc.slew.__class__(**{**sc.slew.__dict__, "R_target": target, "max_accel": 0.08})
    return sc.with_changes(slew=slew)


# ----------------------------------------------------------------------------------------- scenarios
def test_shipped_scenarios_load_and_describe_their_spacecraft():
    assert {"cubesat-1u", "paper-testbed"} <= set(scenario_names())
    cube, bed = load_scenario("cubesat-1u"), load_scenario("paper-testbed")
    assert cube.n_units == 4 and bed.n_units == 3
    assert cube.spacecraft.bus_mass_kg < bed.spacecraft.bus_mass_kg
    assert np.degrees(np.arccos((np.trace(cube.slew.R_target) - 1) / 2)) == pytest.approx(90.0)
    assert "units=3" in bed.emulator_url() and bed.emulator_url().startswith("emu://?")


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("[scenario]\nname='x'\n[manoeuvre]\nangle_degs=3\n", "x.toml: manoeuvre.angle_degs"),
        ("[scenario]\nname='x'\n[manoeuvre]\nmax_rate=-1\n", "x.toml: manoeuvre.max_rate"),
        ("[scenario]\nname='x'\n[sensors.gyr]\nrate_hz='fast'\n", "x.toml: sensors.gyr.rate_hz"),
        ("[scenario]\nname='x'\n[array]\ngeometry='cube'\n", "x.toml: array.geometry"),
        ("[scenario]\nname='x'\n[spacecraft]\npreset='iss'\n", "x.toml: spacecraft.preset"),
        ("[scenario]\nname='x'\n[faults]\nstall=[true]\n", "x.toml: faults.stall"),
        ("[scenario]\nname='x'\n[board]\nframe_rate=20\n", "x.toml: board.frame_rate"),
        ("[scenario]\nname='x'\n[weather]\n", "x.toml"),
        ("[scenario]\n", "x.toml: scenario.name"),
        ("[scenario\nname='x'", "x.toml"),
    ],
)
def test_bad_scenarios_name_the_file_and_key(text, where):
    with pytest.raises(ConfigError) as info:
        parse_scenario(text, Path("x.toml"))
    assert info.value.where == where


def test_unknown_scenario_lists_the_shipped_ones():
    with pytest.raises(ConfigError, match="cubesat-1u"):
        load_scenario("no-such-scenario")


# ----------------------------------------------------------------------------------------- lockstep
@pytest.fixture(scope="module")
def lockstep_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    sc = _quick()
    return sc, run(sc, RunOptions(out_root=out, duration_s=16.0))


def test_lockstep_slew_through_the_protocol_reaches_its_target(lockstep_run):
    sc, result = lockstep_run
    s = result.summary
    assert s["exit"] == "completed" and s["mode"] == "lockstep"
    assert s["slew_started"] and s["failsafe_events"] == 0
    assert s["final_error_deg"] < 1.5  # from 30°, 9 s after the slew (the estimator limits it)
    assert s["peak_error_deg"] > 29.0
    assert s["peak_gimbal_rate"] < sc.spacecraft.limits.max_gimbal_rate
    assert s["min_delta"] > 0.5
    assert s["estimator_rmse_deg"] < 10.0
    assert s["estimator_steps"] > 150 * s["sim_s"]  # the estimator stepped at the fastest sensor's rate
    tasks = s["tasks"]
    assert tasks["control"]["runs"] == pytest.approx(s["sim_s"] * 50, abs=2)
    assert tasks["world"]["runs"] == pytest.approx(s["sim_s"] / World.advance_period_s, abs=2)


def test_one_process_serves_many_runs_without_state_between_them():
    """What a Monte Carlo worker does: run after run in one process. A run, another (other phone seed, a
    link stall), and the first again: the first's trajectory comes back bit for bit, and no run leaves a
    thread behind."""
    import threading

    sc = _quick()
    options = RunOptions(out_root=None, duration_s=0.5)
    threads = threading.active_count()
    first = run(sc, options)
    other = run(sc.with_changes(seed=7, fault_options={"stall": ["1.0:0.4"]}), options)
    again = run(sc, options)
    assert other.summary["failsafe_events"] == 1 and first.summary["failsafe_events"] == 0
    assert not np.array_equal(other.trace.est_err_deg, first.trace.est_err_deg)
    for name in ("t", "point_err_deg", "est_err_deg", "gimbal_rate", "delta"):
        np.testing.assert_array_equal(getattr(again.trace, name), getattr(first.trace, name))
    assert again.summary["phone_samples"] == first.summary["phone_samples"]
    assert threading.active_count() == threads
    assert first.run_dir is None and first.events[0]["kind"] == "connecting"  # events kept in memory


def test_a_world_that_keeps_the_board_current_is_advanced_less_often(monkeypatch):
    """A world declaring ``advance_period_s`` is advanced that often (many plant steps per call), and the
    estimator and control tasks still see the world of their instant: the phone's samples reach the host
    at the same rate, and the run completes."""

    sc = _quick()
    chunked = run(sc, RunOptions(out_root=None, duration_s=0.3))
    monkeypatch.setattr(World, "advance_period_s", None)  # a world that must be advanced every plant step
    every = run(sc, RunOptions(out_root=None, duration_s=0.3))
    every_step, chunk_summary = every.summary, chunked.summary
    assert chunk_summary["exit"] == every_step["exit"] == "completed"
    assert every_step["tasks"]["world"]["runs"] == pytest.approx(every_step["sim_s"] * 1000, abs=2)
    assert chunk_summary["tasks"]["world"]["runs"] == pytest.approx(chunk_summary["sim_s"] * 20, abs=2)
    rates = [s["phone_samples"] / s["sim_s"] for s in (every_step, chunk_summary)]
    assert rates[1] == pytest.approx(rates[0], rel=0.01)
    # the world hands the board its units (and the rotors' accelerations) at the board's own events, and
    # steps ahead to the pulse frames whatever the caller's chunks: the same run
    for name in ("t", "point_err_deg", "est_err_deg", "gimbal_rate", "delta"):
        np.testing.assert_array_equal(getattr(chunked.trace, name), getattr(every.trace, name))


def test_run_directory_holds_telemetry_events_summary_and_scenario(lockstep_run):
    sc, result = lockstep_run
    d = result.run_dir
    tel = read_telemetry(d / "telemetry.csv")
    assert tel.dropped_lines == 0 and tel.rows > 100
    assert set(telemetry_columns(4)) <= set(tel.columns)
    phases = tel["phase"]
    assert phases[0] == 0 and phases[-1] == 2 and np.all(np.diff(phases) >= 0)
    # the board reports the rotors spun up to nominal by the world's physics, commanded through pulses
    assert np.allclose(tel["rotor_speed_0"][-10:], sc.spacecraft.nominal_rotor_speed, rtol=0.05)
    assert np.all((tel["pulse_rotor_0"][-10:] > 1000) & (tel["pulse_rotor_0"][-10:] < 2000))
    hold = tel["est_err_deg"][phases == 2]
    assert hold[-1] < 1.5 and hold[-1] < np.nanmax(hold)  # the estimate converges once the body is still
    events = read_events(d / "events.jsonl")[0]
    times = [e["t"] for e in events]
    assert times == sorted(times), "events.jsonl in time order (the board's boot log before 'armed')"
    kinds = [e["kind"] for e in events]
    for kind in ("connected", "armed", "spin_up", "still_window", "slew_start", "slew_end"):
        assert kind in kinds
    summary = json.loads((d / "summary.json").read_text())
    assert summary["scenario"] == "cubesat-1u"
    assert summary["hil"]["version"] == package_version()  # the code that made the run
    assert (d / "scenario.toml").read_text() == sc.source
    # the coded columns' numbers, named beside them
    codes = json.loads((d / "telemetry_codes.json").read_text())
    assert [codes["phase"]["values"][str(int(p))] for p in (phases[0], phases[-1])] == ["WARMUP", "HOLD"]
    armed = tel["board_state"][phases == 2]
    assert codes["board_state"]["values"][str(int(armed[-1]))] == "ARMED"
    assert codes["faults"]["kind"] == "bits" and codes["faults"]["values"]["2"] == "DEAD_ESC"


def test_with_the_tuned_estimator_the_host_uses_its_online_gyro_bias(tmp_path):
    """The tuned estimator in the loop: by the end of the still window it has found most of the phone
    gyro's bias by itself (rest detection, ~2 s of it); the window's mean becomes its estimate, which it
    keeps refining; the slew completes."""
    sc = _quick().with_changes(estimator=EstimatorChoice("variational", {"preset": "tuned"}))
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=12.0))
    assert result.summary["exit"] == "completed" and result.summary["final_error_deg"] < 3.0
    start = next(e for e in read_events(result.run_dir / "events.jsonl")[0] if e["kind"] == "slew_start")
    still, online = np.asarray(start["gyro_bias"]), np.asarray(start["gyro_bias_online"])
    assert np.linalg.norm(still) > 1e-3 and np.linalg.norm(online - still) < 0.6 * np.linalg.norm(still)


def test_a_link_stall_puts_the_board_in_failsafe_and_the_host_rearms(tmp_path):
    sc = _quick()
    sc = sc.with_changes(fault_options={"stall": ["6.0:0.6"]})  # board time: during the slew
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=16.0))
    s = result.summary
    assert s["exit"] == "completed"
    assert s["failsafe_events"] == 1 and s["rearms"] == 1
    events = read_events(result.run_dir / "events.jsonl")[0]
    assert [e["t"] for e in events] == sorted(e["t"] for e in events)
    states = [e["new"] for e in events if e["kind"] == "board_state"]
    assert "FAILSAFE" in states and states[-1] == "ARMED"
    t_fail = next(e["t"] for e in events if e["kind"] == "board_state" and e["new"] == "FAILSAFE")
    t_back = next(e["t"] for e in events if e["kind"] == "rearmed")
    # the board's watchdog fires 0.25 s into the stall; the host hears of it when the link carries again
    assert 6.25 < t_fail < 6.7 and t_fail < t_back < t_fail + 0.5
    assert s["final_error_deg"] < 2.0  # and the manoeuvre carried on


# ----------------------------------------------------------------------------------------- real time
def _hil(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", *args], capture_output=True, text=True, **kw)


def test_realtime_over_a_pty_against_firmware_sim_with_its_world(tmp_path, phone_port):
    """Two processes as a user runs them: firmware-sim with the world on a pty, streaming its phone over
    UDP as SensaGram does; `hil run --port` against it, in real time."""
    link = tmp_path / "board"
    sim = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--world", "cubesat-1u", "--link", str(link),
         "--phone", f"udp://127.0.0.1:{phone_port}", "--duration", "30"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert sim.stdout is not None and sim.stdout.readline().startswith("/dev/pts/")
        done = _hil(
            "run", "--port", str(link), "--phone", f"127.0.0.1:{phone_port}", "--duration", "1",
            "--no-plots", "--out", str(tmp_path), timeout=60,
        )  # fmt: skip
    finally:
        sim.send_signal(signal.SIGINT)
        sim.wait(timeout=10)
    assert done.returncode == 0, done.stderr
    summary = json.loads(next(tmp_path.glob("*/summary.json")).read_text())
    assert summary["mode"] == "port" and summary["slew_started"]
    assert summary["phone_samples"] > 500  # ~3.5 s of a 450 Hz phone stream arrived over UDP
    phone = summary["phone"]
    assert phone["url"] == f"udp://127.0.0.1:{phone_port}" and phone["bad_messages"] == 0
    assert phone["messages"] == phone["samples"] >= summary["phone_samples"]  # one datagram per sample
    assert summary["tasks"]["control"]["lateness_p50_us"] < 5000
    assert summary["estimator_rmse_deg"] is None  # no truth across the process boundary
    assert "run directory:" in done.stdout


def test_hil_run_prints_its_summary_and_leaves_its_plots(tmp_path):
    """The command as a user runs it: the plots are drawn by a process started before the run and are all
    there when the command returns."""
    done = _hil("run", "--duration", "0.5", "--out", str(tmp_path), timeout=120)
    assert done.returncode in (0, 1), done.stderr  # 1: a 0.5 s run cannot settle
    assert "exit              completed  (lockstep" in done.stdout and "run directory:" in done.stdout
    plots = sorted(p.name for p in next(tmp_path.iterdir()).glob("plots/*.png"))
    assert {"attitude_error.png", "pointing_error.png", "rotor_speeds.png", "delta.png"} <= set(plots)


def test_port_without_a_phone_stream_is_a_clear_error(tmp_path, phone_port):
    done = _hil(
        "run", "--port", "spawn://firmware-sim?units=4", "--phone", f"127.0.0.1:{phone_port}", "--no-plots",
        "--phone-wait", "1", "--out", str(tmp_path), timeout=60,
    )  # fmt: skip
    assert done.returncode == 2
    assert f"no phone stream on udp://127.0.0.1:{phone_port}" in done.stderr and "SensaGram" in done.stderr
    assert "nothing was heard" in done.stderr
    summary = json.loads(next(tmp_path.glob("*/summary.json")).read_text())
    assert summary["exit"].startswith("error: no phone stream")


def test_a_run_killed_with_sigkill_leaves_a_readable_log(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil", "run", "--no-plots", "--out", str(tmp_path)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            files = list(tmp_path.glob("*/telemetry.csv"))
            if files and files[0].stat().st_size > 20_000:
                break
            time.sleep(0.1)
    finally:
        proc.kill()
        proc.wait()
    tel = read_telemetry(files[0])
    assert tel.rows > 20 and tel.dropped_lines <= 1
    assert np.all(np.diff(tel["t"]) > 0)
    events, bad = read_events(files[0].parent / "events.jsonl")
    assert bad <= 1 and events[0]["kind"] == "connecting"
    # `hil report` draws what the killed run logged, without a summary
    done = _hil("report", str(files[0].parent), timeout=120)
    assert done.returncode == 3, done.stderr  # drawn, and said not a whole run
    assert "no summary.json (the run was killed)" in done.stdout
    assert (files[0].parent / "plots" / "rotor_speeds.png").stat().st_size > 10_000


def test_the_same_run_over_a_python_can_virtual_bus(tmp_path, push_port):
    """The board served on a CAN bus (virtual, in this process) with its world streaming the phone over
    HTTP, as Sensor Logger's HTTP Push does."""
    from firmware_sim.cli import build_parser, make_board
    from firmware_sim.servers.can_server import CanServer
    from firmware_sim.world import World, WorldStreamer

    sc = _quick()
    board = make_board(build_parser().parse_args(["--units", "4"]))
    server = CanServer(board, "virtual/runtime-test").start()
    with server.lock:
        world = World(sc, board)
    url = f"http://127.0.0.1:{push_port}/"
    streamer = WorldStreamer(world, server.lock, url).start()
    try:
        result = run(
            sc,
            RunOptions(port="can://virtual/runtime-test", phone=url, duration_s=1.0,
                       out_root=tmp_path),
        )  # fmt: skip
    finally:
        streamer.close()
        server.close()
    s = result.summary
    assert s["exit"] == "completed" and s["slew_started"] and s["failsafe_events"] == 0
    assert s["link"]["transport"]["rx_frames"] > 50  # telemetry came back as reassembled CAN segments
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    assert np.allclose(tel["rotor_speed_0"][-5:], sc.spacecraft.nominal_rotor_speed, rtol=0.05)


def test_hil_report_redraws_a_run_and_prints_its_summary(lockstep_run, tmp_path, capsys):
    import shutil

    from hil.cli import main

    _, result = lockstep_run
    d = tmp_path / "copy"
    shutil.copytree(result.run_dir, d)
    assert not (d / "plots").exists()  # run() draws no plots (the CLI does)
    assert main(["report", str(d)]) == 0
    out = capsys.readouterr().out
    assert f"run {d}: " in out and "exit              completed  (lockstep" in out
    assert f"final error       {result.summary['final_error_deg']:.3f} deg" in out
    assert (d / "plots" / "attitude_error.png").stat().st_size > 10_000 and "attitude_error:" in out
    # a directory that is neither a run nor a campaign, and a missing one: exit 2, the path named
    assert main(["report", str(tmp_path)]) == 2
    assert main(["report", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path}: neither a run directory" in err and "nowhere: no such directory" in err


def test_run_plots_include_the_papers_estimator_figures(lockstep_run):
    from hil.plots.run import plot_run

    _, result = lockstep_run
    paths = plot_run(result.run_dir)
    for name in ("attitude_error", "rate_error", "pointing_error", "gimbal_rates", "rotor_speeds",
                 "pulse_widths", "battery", "delta"):  # fmt: skip
        data = paths[name].read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_gimbal_rates_far_below_their_limit_are_drawn_on_their_own_scale(lockstep_run, monkeypatch):
    """A slew that uses 1 % of the gimbal-rate limit: the axis fits the rates (with the limit named in the
    title), not ±limit, on which they would be a flat line; rates near the limit show it as lines."""
    import hil.plots.run as plots

    _, result = lockstep_run
    seen = {}
    real_save = plots._save

    def flat(values):
        return len(set(np.ravel(values).tolist())) == 1

    def save(fig, ax, path):
        data = [line for line in ax.lines if not flat(line.get_xdata()) and not flat(line.get_ydata())]
        horizontal = [line for line in ax.lines if flat(line.get_ydata())]  # limit lines
        seen[path.stem] = (ax.get_ylim(), ax.get_title(), len(data), len(horizontal))
        return real_save(fig, ax, path)

    monkeypatch.setattr(plots, "_save", save)
    plots.plot_run(result.run_dir)
    (low, high), title, lines, limit_lines = seen["gimbal_rates"]
    peak, limit = result.summary["peak_gimbal_rate"], result.summary["max_gimbal_rate_limit"]
    assert peak < 0.25 * limit and high < 2 * peak and low > -2 * peak
    assert "off the scale" in title and f"{limit:g}" in title
    assert lines == 4 and limit_lines == 0  # the four units (and the run's event markers), no limit lines


def test_the_printed_summary_explains_delta_and_a_missing_estimator_rmse():
    """A newcomer reads what "minimum delta" measures, and why an estimator RMSE is "-" (no truth)."""
    from hil.cli.run import format_summary

    with_truth = format_summary({"exit": "completed", "min_delta": 1.19, "estimator_rmse_deg": 4.2})
    without = format_summary({"exit": "completed", "min_delta": 0.02, "estimator_rmse_deg": None})
    assert "0 is singular" in with_truth and "(slew + hold)" in with_truth
    assert "estimator RMSE    - (no ground truth in this run)" in without
