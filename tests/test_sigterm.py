"""SIGTERM ends ``hil`` commands the way Ctrl-C does (issue 25, finding 3), with real processes.

``timeout``, systemd and a CI runner's cancel send SIGTERM; it once killed ``hil run`` at once (status 143,
no summary, no Disarm: only the board's link watchdog made it safe). Now both signals raise the same
interrupt (``hil.cli._signals``): a run writes its summary with the signal in its exit reason, disarms the
board it armed before closing the port (``events.jsonl``: ``disarmed``), and exits 1 as documented
(docs/faults.md); other commands end cleanly with 128 + the signal. The board's side is read from
firmware-sim's own log (``-v``: every board ``Log``, its state changes among them). Every wait is a
deadline loop on what the processes wrote, so a busy machine makes these slower, not wrong; firmware-sim's
link timeout is 1 s, so a host that is slow to send its Disarm under load is not taken for one that sent
none (a board that is never disarmed logs ``ARMED -> FAILSAFE`` a second after the host went quiet).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

from hil.runtime.runlog import read_events, read_telemetry
from hil.scenario import SCENARIO_DIR
from hil.scenario.paths import ROOT, SHARED_DATA

SENSORLOGGER = SHARED_DATA / "sensorlogger-android"
LINK_TIMEOUT_S = 1.0


def _wait_until(condition: Callable[[], object], timeout: float, what: str, proc=None) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the process ended (status {proc.returncode}) before {what}")
        time.sleep(0.02)
    raise AssertionError(f"not within {timeout} s: {what}")


def _spawn(*args: str, log: Path, **kw) -> subprocess.Popen:
    """``python -m MODULE ARGS`` with stdout and stderr into ``log`` (.out/.err): a pipe nobody reads could
    fill and stall it."""
    out = open(log.with_suffix(".out"), "w")  # noqa: SIM115 — the child holds them; closed on exit
    err = open(log.with_suffix(".err"), "w")  # noqa: SIM115
    try:
        return subprocess.Popen([sys.executable, "-m", *args], stdout=out, stderr=err, cwd=ROOT, **kw)
    finally:
        out.close()
        err.close()


def _text(path: Path) -> str:
    return path.read_text(errors="replace") if path.exists() else ""


def _kinds(run_dir: Path) -> list[str]:
    path = run_dir / "events.jsonl"
    return [e["kind"] for e in read_events(path)[0]] if path.exists() else []


def _run_dir(out: Path) -> Path | None:
    dirs = list(out.glob("*/events.jsonl")) if out.exists() else []
    return dirs[0].parent if dirs else None


@dataclass
class Sim:
    proc: subprocess.Popen
    link: Path
    err: Path

    def log(self) -> str:
        return _text(self.err)

    def states(self) -> list[str]:
        """The board's state changes, in order (``DISARMED -> ARMED``, ...)."""
        return [line.split("state ", 1)[1] for line in self.log().splitlines() if "STATE: state " in line]


@contextmanager
def firmware_sim(tmp_path: Path, *extra: str) -> Iterator[Sim]:
    """firmware-sim on a pty behind ``tmp_path/board``, logging every board Log; stopped (SIGINT) after."""
    link = tmp_path / "board"
    base = tmp_path / "firmware-sim"
    proc = _spawn(
        "firmware_sim", "--link", str(link), "--link-timeout", str(LINK_TIMEOUT_S), "-v", *extra, log=base
    )
    sim = Sim(proc, link, base.with_suffix(".err"))
    try:
        _wait_until(link.exists, 60.0, "firmware-sim's pty link", proc)
        yield sim
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextmanager
def reaped(proc: subprocess.Popen) -> Iterator[subprocess.Popen]:
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _interrupted_run(out: Path, proc: subprocess.Popen, signum: int, log: Path) -> tuple[dict, Path]:
    """Signal ``proc`` (a run) once its board is armed and its rotors commanded (``spin_up``) and rows are
    being written; its summary and run directory after it ended with status 1."""
    _wait_until(
        lambda: _run_dir(out) is not None and "spin_up" in _kinds(_run_dir(out)),
        120.0,
        "the run armed the board and spun its rotors up",
        proc,
    )
    run_dir = _run_dir(out)
    assert run_dir is not None
    csv = run_dir / "telemetry.csv"
    _wait_until(lambda: csv.exists() and _text(csv).count("\n") > 30, 60.0, "rows in telemetry.csv", proc)
    proc.send_signal(signum)
    status = proc.wait(timeout=60)
    name = signal.Signals(signum).name
    assert status == 1, f"status {status}; stderr: {_text(log.with_suffix('.err'))}"
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["exit"] == f"interrupted ({name})"
    events = read_events(run_dir / "events.jsonl")[0]
    disarmed = [e for e in events if e["kind"] in ("disarmed", "disarm_failed")]
    assert [(e["kind"], e["reason"]) for e in disarmed] == [("disarmed", f"interrupted ({name})")]
    assert [e["t"] for e in events] == sorted(e["t"] for e in events)
    tel = read_telemetry(csv)
    assert tel.rows >= 30 and tel.dropped_lines == 0  # at least the rows waited for (31 lines: the header)
    return summary, run_dir


def _board_disarmed_by_the_host(sim: Sim) -> None:
    """The board's last state change, read from firmware-sim's log once the host has been gone past the
    link timeout, is ARMED -> DISARMED: the host's Disarm, within the link timeout of its last frame. A
    board nobody disarmed ends ARMED -> FAILSAFE; one disarmed late, FAILSAFE -> DISARMED. (A FAILSAFE
    earlier in the run, from a host stalled past the timeout on a loaded machine and re-armed since, is
    the run's business, not this test's.)"""
    time.sleep(LINK_TIMEOUT_S + 0.5)
    _wait_until(lambda: sim.states(), 10.0, "a state change in firmware-sim's log")
    states = sim.states()
    assert "DISARMED -> ARMED" in states, sim.log()
    assert states[-1] == "ARMED -> DISARMED", states


def test_sigterm_mid_run_disarms_the_board_and_writes_the_summary(tmp_path, phone_port):
    """`hil run --port` against firmware-sim with its world, as `timeout` would stop it."""
    phone = f"udp://127.0.0.1:{phone_port}"
    with firmware_sim(tmp_path, "--world", "cubesat-1u", "--phone", phone) as sim:
        out = tmp_path / "runs"
        args = (
            "hil",
            "run",
            "--port",
            str(sim.link),
            "--phone",
            phone,
            "--duration",
            "120",
            "--no-plots",
            "--out",
            str(out),
        )
        with reaped(_spawn(*args, log=tmp_path / "hil")) as hil:
            summary, _ = _interrupted_run(out, hil, signal.SIGTERM, tmp_path / "hil")
        assert summary["mode"] == "port"
        assert "exit              interrupted (SIGTERM)" in _text(tmp_path / "hil.out")
        _board_disarmed_by_the_host(sim)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_an_interrupted_lockstep_run_disarms_the_built_in_board(tmp_path, signum):
    """The built-in emulator paced to the wall clock (so it is still running when the signal comes): the
    same exit, for either signal, and the in-process board disarmed (before, SIGINT wrote ``interrupted``
    and left the board armed; SIGTERM wrote nothing)."""
    out = tmp_path / "runs"
    args = ("hil", "run", "--pace", "1", "--duration", "120", "--no-plots", "--out", str(out))
    with reaped(_spawn(*args, log=tmp_path / "hil")) as hil:
        summary, _ = _interrupted_run(out, hil, signum, tmp_path / "hil")
    assert summary["mode"] == "lockstep"


def test_sigterm_stops_the_ground_station_cleanly(tmp_path):
    """`hil gcs RUN_DIR` serves until stopped: SIGTERM is that stop, as Ctrl-C is (status 0)."""
    from hil.runtime import RunOptions, run
    from hil.scenario import load_scenario

    result = run(load_scenario("cubesat-1u"), RunOptions(out_root=tmp_path / "runs", duration_s=0.2))
    assert result.run_dir is not None
    args = ("hil", "gcs", str(result.run_dir), "--gcs", "127.0.0.1:0", "--no-follow")
    with reaped(_spawn(*args, log=tmp_path / "gcs")) as gcs:
        _wait_until(lambda: "ground station: http" in _text(tmp_path / "gcs.out"), 60.0, "its URL", gcs)
        gcs.send_signal(signal.SIGTERM)
        status = gcs.wait(timeout=30)
    assert status == 0, _text(tmp_path / "gcs.err")


def test_sigterm_mid_replay_disarms_the_board(tmp_path):
    """`hil replay LOG --port` against firmware-sim (the recording is the phone)."""
    with firmware_sim(tmp_path) as sim:
        out = tmp_path / "runs"
        args = ("hil", "replay", str(SENSORLOGGER), "--port", str(sim.link), "--no-plots", "--out", str(out))
        with reaped(_spawn(*args, log=tmp_path / "hil")) as hil:
            summary, _ = _interrupted_run(out, hil, signal.SIGTERM, tmp_path / "hil")
        assert summary["source"] == "log"
        _board_disarmed_by_the_host(sim)


def test_sigterm_mid_sweep_puts_the_bench_back_to_rest(tmp_path):
    """`hil calibrate sweep` against firmware-sim: the board disarmed and back in SETPOINT mode, status 143
    (128 + SIGTERM: a command without a run summary of its own)."""
    with firmware_sim(tmp_path) as sim:
        args = (
            "hil",
            "calibrate",
            "sweep",
            "--port",
            str(sim.link),
            "--unit",
            "0",
            "--map",
            "rotor",
            "--out-dir",
            str(tmp_path / "bench"),
        )
        with reaped(_spawn(*args, log=tmp_path / "hil")) as hil:
            # prepare() arms and disarms once; the second Arm starts the sweep proper
            _wait_until(lambda: sim.states().count("DISARMED -> ARMED") >= 2, 120.0, "the sweep armed", hil)
            time.sleep(0.5)
            hil.send_signal(signal.SIGTERM)
            status = hil.wait(timeout=60)
        assert status == 128 + signal.SIGTERM, _text(tmp_path / "hil.err")
        assert "hil calibrate: interrupted (SIGTERM)" in _text(tmp_path / "hil.err")
        _board_disarmed_by_the_host(sim)
        assert sim.log().rindex("mode SETPOINT") > sim.log().rindex("mode RAW_PULSES")


def test_sigterm_ends_a_campaign_cleanly_with_its_workers(tmp_path):
    """`hil montecarlo` (a LocalCluster of worker processes) gets SIGTERM in its own process only, as
    `timeout` sends it: the finished runs are on disk, status 143, and no process of its session is left
    (its cluster's workers were stopped, not orphaned)."""
    text = (SCENARIO_DIR / "cubesat-1u.toml").read_text()
    for old, new in (
        ("duration_s = 35.0", "duration_s = 1.0"),
        ("warmup_s = 2.0", "warmup_s = 0.5"),
        ("angle_deg = 90.0", "angle_deg = 20.0"),
    ):
        assert old in text
        text = text.replace(old, new)
    scenario = tmp_path / "quick.toml"
    scenario.write_text(text)
    out = tmp_path / "mc"
    runs = out / "runs.csv"
    args = (
        "hil",
        "montecarlo",
        str(scenario),
        "--runs",
        "40",
        "--workers",
        "1",
        "--batch",
        "1",
        "--out",
        str(out),
        "--no-plots",
    )
    with reaped(_spawn(*args, log=tmp_path / "hil", start_new_session=True)) as hil:
        _wait_until(lambda: _text(runs).count("\n") >= 2, 120.0, "a finished run in runs.csv", hil)
        hil.send_signal(signal.SIGTERM)
        status = hil.wait(timeout=60)
    assert status == 128 + signal.SIGTERM, _text(tmp_path / "hil.err")
    assert "hil montecarlo: interrupted (SIGTERM)" in _text(tmp_path / "hil.err")
    assert _text(runs).count("\n") >= 2

    def session_gone() -> bool:
        try:
            os.killpg(hil.pid, 0)
        except ProcessLookupError:
            return True
        return False

    try:
        _wait_until(session_gone, 30.0, "every process of the campaign's session ended")
    finally:
        if not session_gone():
            os.killpg(hil.pid, signal.SIGKILL)
