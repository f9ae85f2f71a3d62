"""Fault campaigns for the tools that drive a board besides ``hil run``: ``hil calibrate`` (handshake, ESC
endpoint teaching, sweeps, the upload of calibration sets, verification) and ``hil replay LOG --port``
(at the start, mid-log, in the last second). Each board is ``firmware-sim`` in a process of its own behind
a real pty; the faults are done to that process — killed (SIGKILL) and started again on the same ``--link``
path, or not, or stopped (SIGSTOP) for a drawn time and let go — at seeded drawn moments of every phase
(a run's moment is its printed progress line plus a drawn delay; the upload's, the fragment just sent).

Invariants, on what each run left (exit status, output, files, the board itself afterwards): the tool
ends within a bounded wall time and never with a traceback; its exit status and final message are honest
(a sweep, ESC procedure, upload or verification cut short is not reported done; a calibration whose board
was lost or reset mid-upload or mid-verification writes no file, says what the board holds, and the board
holds exactly that — its previous set, read back after a restart); the board, when it is still there, is
left at rest (not ARMED, not teaching an ESC, rotors at their minimum pulse); what a sweep measured before
the fault is kept in its bench CSV, marked partial; each fault is reported once.

Defects these found (each a regression test below):

* a board killed (or reset) while it taught an ESC: ``hil calibrate esc`` waited out the procedure's whole
  time and then blamed the board for reporting no end (``no end reported (last phase: HIGH)``), never
  saying the board had gone;
* a board killed mid-sweep and not back: the step waited out ``--settle-max`` and the sweep failed with
  ``the board's telemetry never showed the command``; a board restarted mid-sweep was reported as one that
  ``left ARMED (DISARMED)``, its reset unsaid;
* a board stalled (or lost) during verification: the error (``Disarm ... no answer``, ``left ARMED
  (FAILSAFE)``) ended ``hil calibrate unit`` with the new, unverified set left on the board — the previous
  sets are put back only when a point missed its tolerance — and nothing said so; a board lost mid-upload
  likewise left whatever part it held unsaid. Now the previous sets are put back and read back wherever
  the board can be reached, and the message says what the board holds;
* a command that failed after moving the outputs never put them back to rest or said their state (only an
  interrupt did).
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from operator_support import Operated
from sim_support import Sim

from hil.calibration.bench import read_bench_csv
from hil.calibration.benchlink import BenchLink
from hil.calibration.files import load_calibration
from hil.cli import main
from hil.link.board import BoardClient
from hil.scenario.paths import SHARED_DATA
from protocol.calibration import default_unit_calibration
from protocol.messages import BoardState, CalibrationData, ControlMode

ROOT = Path(__file__).resolve().parents[1]
SEED = int(os.environ.get("FAULT_SEED", "20261205"))
"""The campaign's draws (fault moments, lengths): fixed, so a failure replays; ``FAULT_SEED`` draws others."""
LINK_TIMEOUT = "1"  # the boards' link watchdog (s): a loaded CPU may delay a heartbeat by more than 0.25 s
SIM = ["--units", "2", "--unit-spread", "3", "--esc-supply-switch", "--link-timeout", LINK_TIMEOUT]
QUICK_ESC = ["--supply-off-ms", "300", "--high-ms", "1500", "--low-ms", "1000"]
QUICK_RATE = ["--directions", "up", "--settle", "0.1", "--settle-window", "0.1", "--dwell", "0.05"]
SENSORLOGGER = SHARED_DATA / "sensorlogger-android"
WALL_S = 60.0  # every tool run ends within this (bounded wall time, generous on a busy machine)
AFTER_FAULT_S = 15.0  # ... and within this once the fault is done (a lost board is seen within ~1 s)


class Bench:
    """The boards of one test on one ``--link`` path: the first started at once, more by faults."""

    def __init__(self, tmp: Path, *options: str) -> None:
        self.tmp, self.options = tmp, options
        self.link = tmp / "board"
        self.sims = [Sim(tmp, self.link, *options)]
        self.done: list[str] = []  # the faults done, in words

    @property
    def sim(self) -> Sim:
        return self.sims[-1]

    def fault(self, kind: str, seconds: float) -> None:
        """``kill``: SIGKILL, a new board on the same path ``seconds`` later; ``kill-gone``: SIGKILL and
        its path removed, as a board unplugged; ``stop``: SIGSTOP for ``seconds``, then SIGCONT."""
        sim = self.sim
        if kind == "stop":
            sim.proc.send_signal(signal.SIGSTOP)
            time.sleep(seconds)
            sim.proc.send_signal(signal.SIGCONT)
        else:
            sim.kill()
            if kind == "kill-gone":  # unplugged: its port goes too (a stale link could reach a reused pty)
                self.link.unlink(missing_ok=True)
            if kind == "kill":
                time.sleep(seconds)
                self.sims.append(Sim(self.tmp, self.link, *self.options))
        self.done.append(f"{kind} {seconds:.2f} s")

    def close(self) -> None:
        for sim in self.sims:
            sim.kill()


@contextlib.contextmanager
def bench(tmp: Path, *options: str) -> Iterator[Bench]:
    b = Bench(tmp, *options)
    try:
        yield b
    finally:
        b.close()


def draw_fault(
    rng: random.Random, kinds: tuple[str, ...] = ("kill", "kill-gone", "stop")
) -> tuple[str, float]:
    kind = rng.choice(kinds)
    # a stop from well inside the board's link watchdog (1 s) to well past it
    return kind, rng.uniform(0.3, 1.2) if kind == "kill" else rng.uniform(0.4, 1.8)


# ====================================================================== invariants
def board_state(b: Bench) -> tuple[object, bytes] | None:
    """The last board's telemetry and unit 0's calibration set, read by a fresh host; None if it is gone."""
    if not b.sim.alive:
        return None
    client = BoardClient(str(b.link))
    client.connect()
    try:
        tel = BenchLink(client).latest(timeout=3.0)
        return tel, client.download_calibration(0).to_bytes()
    finally:
        client.close()


def check_at_rest(b: Bench) -> bytes | None:
    """The board, if there, is at rest: not ARMED, no ESC being taught, every rotor at its minimum pulse.
    Returns what it holds for unit 0."""
    seen = board_state(b)
    if seen is None:
        return None
    tel, held = seen
    assert tel.state is not BoardState.ARMED and tel.mode is not ControlMode.ESC_CALIBRATION, (tel, b.done)
    assert all(w == 1000 for w in tel.pulses_us[1::2]), (tel.pulses_us, b.done)
    return held


def check_honest_end(code: int, out: str, err: str, b: Bench) -> None:
    """No traceback; an error is said once, as the last line; a failure never as a success."""
    assert "Traceback" not in err, err
    assert code in (0, 1, 2), (code, err, b.done)
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == (code == 2), (errors, b.done)
    if code == 2:
        assert err.rstrip().splitlines()[-1] == errors[0]


def run_tool(argv: list[str], trigger: str | None, delay: float, b: Bench, fault: tuple[str, float]):
    """``python -m hil ARGV`` (stdin a pty); ``fault`` done ``delay`` s after the first stdout line with
    ``trigger`` (None: after ``delay`` from the start). Returns exit status, stdout, stderr and the wall
    time from the fault to the end, each bounded."""
    op = Operated(argv)
    t0 = time.monotonic()
    if trigger is not None:
        op.wait_for(trigger, timeout=WALL_S)
    time.sleep(delay)
    hit = time.monotonic()
    b.fault(*fault)
    code, err = op.finish(timeout=WALL_S)
    end = time.monotonic()
    assert end - t0 < WALL_S, (end - t0, b.done)
    return code, op.stdout, err, end - hit


# ====================================================================== hil calibrate esc
ESC_MOMENTS = ("handshake", "step 1/3 SUPPLY_OFF", "step 2/3 HIGH", "step 3/3 LOW")


@pytest.mark.parametrize("moment", ESC_MOMENTS)
def test_esc_teaching_faults_at_drawn_moments(tmp_path, moment):
    rng = random.Random(SEED * 10 + ESC_MOMENTS.index(moment))
    fault = draw_fault(rng)
    argv = ["calibrate", "esc", "--port", "", "--unit", "0", "--confirm-unloaded", *QUICK_ESC]
    with bench(tmp_path, *SIM) as b:
        argv[3] = str(b.link)
        if moment == "handshake":  # the board says nothing until the fault: the tool is in its Hellos
            b.sim.proc.send_signal(signal.SIGSTOP)
            code, out, err, after = run_tool(argv, None, rng.uniform(0.3, 0.9), b, fault)
        else:
            code, out, err, after = run_tool(argv, moment, rng.uniform(0.0, 0.25), b, fault)
        check_honest_end(code, out, err, b)
        taught = "unit 0: ESC taught 1000-2000 us" in out
        assert taught == (code == 0) and taught == ("unit 0 ESC: DONE" in out), (out, err, b.done)
        if moment == "handshake" and code == 2:  # the board went under the first handshake
            assert "no session with the board at" in err and "nothing was done" in err, err
        if moment != "handshake" and fault[0] != "stop":
            # the procedure died with its board: said at once, as such (it used to wait out its time and
            # blame the board for reporting no end)
            assert code == 2 and "its ESC was not taught" in err and "the board link was lost" in err, err
            assert after < 6.0, (after, err)
        assert after < AFTER_FAULT_S
        check_at_rest(b)


# ====================================================================== hil calibrate sweep
@pytest.mark.parametrize("index", range(2))
def test_sweep_faults_at_drawn_steps_keep_what_was_measured(tmp_path, index):
    rng = random.Random(SEED * 20 + index)
    step = rng.randint(2, 20)
    fault = draw_fault(rng, ("kill-gone",) if index == 0 else ("kill", "stop"))
    with bench(tmp_path, *SIM) as b:
        argv = ["calibrate", "sweep", "--port", str(b.link), "--unit", "0", "--map", "gimbal_rate"]
        argv += ["--out-dir", str(tmp_path), "--step", "40", *QUICK_RATE]
        code, out, err, after = run_tool(argv, f"gimbal_rate sweep {step}/26", rng.uniform(0, 0.3), b, fault)
        check_honest_end(code, out, err, b)
        assert after < AFTER_FAULT_S, (after, err)
        data = read_bench_csv(tmp_path / "unit0_gimbal_rate.csv")
        kept = [line for line in out.splitlines() if "partial bench CSV kept" in line]
        if code == 0:  # a stall the sweep rode out
            assert data.partial is None and len(data) == 26 and not kept and "26 steps" in out
        else:
            assert code == 2 and data.partial is not None and len(kept) == 1, (out, err)
            assert (
                step <= len(data) < 26 and f"{len(data)} of 26 steps" in kept[0] and "failed:" in data.partial
            )
        if fault[0] == "kill-gone":
            # said at once and as such (it used to wait out --settle-max, then blame the telemetry)
            assert "the board link was lost" in err and "during the gimbal_rate sweep" in err, err
            assert "board cannot be reached" in err and after < 6.0, (after, err)
        if fault[0] == "kill":
            assert "the board link was lost" in err or "the board reset" in err, err
        check_at_rest(b)


# ====================================================================== hil calibrate unit: upload, verify
def unit_argv(link: Path, tmp: Path) -> list[str]:
    argv = ["calibrate", "unit", "--port", str(link), "--unit", "0", "--maps", "gimbal_rate"]
    return [*argv, "-o", str(tmp / "cal.toml"), "--bench-dir", str(tmp), "--rate-step", "40", *QUICK_RATE]


def check_calibration_end(code: int, out: str, err: str, b: Bench, tmp: Path) -> bytes | None:
    """Saved and on the board, or neither: a failed run writes no file and the board holds its previous
    set (the default unit) whenever the message says so — and after a restart, whatever it says."""
    check_honest_end(code, out, err, b)
    held = check_at_rest(b)
    saved = tmp / "cal.toml"
    if code == 0:
        assert "saved units [0]" in out and saved.exists()
        assert held is None or held == load_calibration(saved).unit(0).calibration.to_bytes()
        return held
    assert not saved.exists() and "did not finish" in err and "the file was not written" in err, err
    assert "saved units" not in out
    says_previous = "the board holds the previous sets of units [0], read back" in err
    assert says_previous or "could not be put back" in err, err
    if held is not None and (says_previous or len(b.sims) > 1):
        assert held == default_unit_calibration().to_bytes(), (err, b.done)
    return held


@pytest.mark.parametrize("index", range(2))
def test_upload_faults_with_fragments_in_flight(tmp_path, monkeypatch, capsys, index):
    """The fault is done right after the drawn fragment of the set went out (in-process: the hook is the
    client's command), the board's answer to it still in flight."""
    rng = random.Random(SEED * 30 + index)
    fragment = rng.randint(0, 2)  # a 414-byte set: three fragments
    fault = draw_fault(rng, ("kill", "stop") if index == 0 else ("kill-gone", "kill", "stop"))
    with bench(tmp_path, *SIM) as b:
        send = BoardClient.command
        threads: list[threading.Thread] = []

        def command(client, message):
            cmd = send(client, message)
            if isinstance(message, CalibrationData) and message.index == fragment and not threads:
                threads.append(threading.Thread(target=b.fault, args=fault))
                threads[0].start()
                if fault[0] != "stop":
                    b.sims[0].proc.wait(timeout=10)  # killed before the next fragment goes out
            return cmd

        monkeypatch.setattr(BoardClient, "command", command)
        t0 = time.monotonic()
        code = main(unit_argv(b.link, tmp_path))
        assert time.monotonic() - t0 < WALL_S
        for t in threads:
            t.join(timeout=10)
        captured = capsys.readouterr()
        assert threads, captured.out  # the fault was done
        monkeypatch.undo()
        check_calibration_end(code, captured.out, captured.err, b, tmp_path)
        if fault[0] != "stop":
            assert code == 2 and "the upload of unit 0's set did not finish" in captured.err


VERIFY_FAULTS = (("stop", 2.0), ("kill", 0.6))


@pytest.mark.parametrize("fault", VERIFY_FAULTS, ids=[f[0] for f in VERIFY_FAULTS])
def test_verification_faults_put_the_previous_set_back(tmp_path, fault):
    """A board stalled past its link watchdog, or restarted, at a drawn verification point: the run fails,
    writes no file and the board holds its previous set again (it used to keep the new, unverified one)."""
    rng = random.Random(SEED * 40 + VERIFY_FAULTS.index(fault))
    point = rng.randint(1, 4)
    with bench(tmp_path, *SIM) as b:
        code, out, err, after = run_tool(unit_argv(b.link, tmp_path), f"verify {point}/5", 0.0, b, fault)
        assert code == 2 and "verification did not finish" in err, (out, err)
        assert after < AFTER_FAULT_S
        held = check_calibration_end(code, out, err, b, tmp_path)
        assert held == default_unit_calibration().to_bytes()  # not the new set, never verified


# ====================================================================== hil replay --port
REPLAY_MOMENTS = {"start": (0.6, 1.8), "mid-log": (2.5, 4.0), "last second": (4.6, 5.4)}


@pytest.mark.parametrize("moment", list(REPLAY_MOMENTS))
def test_replay_faults_at_drawn_moments(tmp_path, moment):
    """``hil replay --port`` on 4 s of a Sensor Logger export (its run starts ~1.5 s after launch)."""
    rng = random.Random(SEED * 50 + list(REPLAY_MOMENTS).index(moment))
    at = rng.uniform(*REPLAY_MOMENTS[moment])
    fault = draw_fault(rng)
    out_root = tmp_path / "runs"
    with bench(tmp_path, "--units", "4", "--telemetry-rate", "50", "--link-timeout", LINK_TIMEOUT) as b:
        argv = ["replay", str(SENSORLOGGER), "--port", str(b.link), "--window", "0", "4"]
        code, out, err, after = run_tool([*argv, "--out", str(out_root), "--no-plots"], None, at, b, fault)
        assert "Traceback" not in err, err
        runs = list(out_root.glob("*/summary.json"))
        if not runs:  # the board went before the run could start: an error, said once
            assert code == 2 and err.count(": error: ") == 1, (out, err, b.done)
            return
        s = json.loads(runs[0].read_text())
        if s["exit"].startswith("error"):  # gone before its first session, not back: its summary says so
            assert code == 2 and err.count(": error: ") == 1 and fault[0] == "kill-gone", (s["exit"], err)
            return
        exit_line = next(line for line in out.splitlines() if line.startswith("exit "))
        assert s["exit"] in exit_line
        if s["exit"] == "completed":
            assert code == 0 and s["replay"]["samples_released"] == s["phone_samples"]
        elif s["exit"].startswith("incomplete"):  # a restart's warm-up the recording's end cut short
            assert code == 1 and "before the slew started" in s["exit"], (exit_line, b.done)
        else:
            assert code == 3 and "completed" not in exit_line, (exit_line, b.done)
        started = any(f["kind"] == "link_lost" for f in s["faults"]) or s["board_resets"]
        if fault[0] == "kill-gone" and started:  # lost and not back: never completed
            assert s["exit"].startswith("lost"), (s["exit"], b.done)
        # each fault reported once: one loss per kill, one reset per restart seen
        assert sum(f["kind"] == "link_lost" for f in s["faults"]) <= 1, s["faults"]
        assert s["board_resets"] <= 1 and after < AFTER_FAULT_S
        check_at_rest(b)
