"""The host through board faults (issue 16): findings 1-3 and 7 as regression tests, in lockstep through the
emulated board's own fault injection, and in real time against firmware-sim on a pty killed as a user
would kill it.

1. a board that resets (its rotors stopped) while the host steers: no crash; the host re-arms through the
   protocol and re-enters its warm-up before it steers again;
2. no telemetry: rows say so (board_link, a growing tel_age_ms) and carry no board value;
3. a board that never comes back: the run ends lost (exit status 3), its summary says when and how long;
7. the real-time host loads its compiled kernels before it arms the board.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from observer_support import SilentObserver

from hil.cli.run import EXIT_LOST, exit_status, format_summary
from hil.link.board import BoardClient
from hil.link.board.events import StateEvent
from hil.runtime import RunOptions, run
from hil.runtime.faults import BoardLink
from hil.runtime.runlog import EventLog, read_events, read_telemetry
from hil.runtime.telemetry import board_columns
from hil.scenario import load_scenario
from hil.timing.clock import LockstepClock
from protocol.messages import BoardState

ROOT = Path(__file__).resolve().parents[1]
DT = 0.02  # the scenarios' control period (s)


def _quick(**faults: list[str]):
    """cubesat-1u with a 30° slew (as tests/test_runtime.py) and these board faults."""
    from hil import so3

    sc = load_scenario("cubesat-1u")
    axis = so3.log(sc.slew.R0.T @ sc.slew.R_target)
    target = sc.slew.R0 @ so3.exp(axis / np.linalg.norm(axis) * np.radians(30.0))
    slew = sc.slew.__class__(**{**sc.slew.__dict__, "R_target": target, "max_accel": 0.08})
    return sc.with_changes(slew=slew, fault_options=faults)


def _run(tmp_path, sc, **options):
    result = run(sc, RunOptions(out_root=tmp_path, **options))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    events, bad = read_events(result.run_dir / "events.jsonl")
    assert bad == 0 and tel.dropped_lines == 0
    return result, tel, events


def _first(events, kind, after=-np.inf, **match):
    def fits(e):
        return e["kind"] == kind and e["t"] > after and all(e.get(k) == v for k, v in match.items())

    return next(e for e in events if fits(e))


def _blind_rows_are_empty(tel, n=4):
    """No stale row: a row whose board_link is not live has no board value at all; a live row's
    telemetry is younger than the stale bound."""
    link = tel["board_link"]
    blind = link != int(BoardLink.LIVE)
    for name in board_columns(n):
        assert np.all(np.isnan(tel[name][blind])), name
    assert np.all(tel["tel_age_ms"][~blind] <= 250.0 + 1e-6)
    return blind


# ----------------------------------------------------------------------------------------- lockstep
def test_a_hung_board_goes_stale_resets_and_the_host_warms_up_before_it_steers(tmp_path):
    """Findings 1 and 2 in lockstep: the MCU hangs 1.3 s into the slew. Its telemetry stops: 0.25 s later
    the rows turn stale (no board value, the age growing) and the host sends nothing but one hold; the
    MCU watchdog resets the board (cause WATCHDOG); the host re-arms after the new handshake, and does not
    steer again (gimbal-rate commands zero, warm-up phase) until the rotors are back at speed and every
    check holds; then it slews anew to the target."""
    result, tel, events = _run(tmp_path, _quick(hang_at=["4.0"]), duration_s=14.0)
    s = result.summary
    assert s["exit"] == "completed" and s["board_resets"] == 1 and s["rearms"] == 1 and s["lost"] is None
    reset = _first(events, "board_reset")
    assert reset["cause"] == "WATCHDOG"
    stale = next(f for f in s["faults"] if f["kind"] == "stale")
    assert 4.0 + 0.2 < stale["t"] <= 4.0 + 0.25 + 2 * DT  # 0.25 s after the last telemetry, within a tick
    rearmed = _first(events, "rearmed", after=reset["t"] - 1e-9)
    resume = _first(events, "resume", after=rearmed["t"] - 1e-9)
    back = _first(events, "board_back", after=stale["t"])
    assert back["t"] <= resume["t"] and back["causes"] == ["stale", "reset"]
    assert s["outages"][0]["recovered"] and s["outages"][0]["duration_s"] < 1.0

    t = tel["t"]
    blind = _blind_rows_are_empty(tel)
    out = (t >= stale["t"] - 1e-9) & (t < back["t"] - 1e-9)
    assert np.all(blind[(t >= stale["t"] - 1e-9) & (t < reset["t"] - 1e-9)])  # hung, then handshaking
    age = tel["tel_age_ms"][(t >= stale["t"] - 1e-9) & (t < reset["t"] - 1e-9)]
    assert np.all(np.diff(age) > 0) and age[0] > 250.0  # the age grows: nothing repeated as fresh
    assert out.sum() >= 10
    recovering = (t >= reset["t"] - 1e-9) & (t < resume["t"] - 1e-9)
    assert np.all(tel["phase"][recovering] == 0)
    commanded = tel["cmd_gimbal_rate_0"][recovering]
    assert np.all((commanded == 0.0) | np.isnan(commanded))  # no steering while it recovers
    assert np.all(tel["phase"][t > resume["t"] + 1e-9] > 0)
    assert np.nanmax(np.abs(tel["cmd_gimbal_rate_0"][t > resume["t"] + 0.1])) > 0  # steering again


def test_a_board_that_never_comes_back_ends_the_run_lost(tmp_path):
    """Finding 3 in lockstep: the link stalls for good 5 s into the run. The run does not go on "controlling"
    a board it cannot hear: it ends 2 s (--recover-within) after losing it, its exit reason says when and
    how long, every later row is stale, and hil run's exit status is 3."""
    result, tel, events = _run(tmp_path, _quick(stall=["5.0:100"]), duration_s=30.0, recover_within_s=2.0)
    s = result.summary
    assert s["exit"].startswith("lost: board lost at t=5.2") and "for 2.0 s (stale)" in s["exit"]
    assert s["lost"] == s["exit"][len("lost: ") :]
    assert exit_status(s) == EXIT_LOST
    outage = s["outages"][-1]
    assert outage["recovered"] is False and outage["start"] == pytest.approx(5.26, abs=0.03)
    assert tel["t"][-1] == pytest.approx(outage["start"] + 2.0, abs=2 * DT)  # at the bound, not 30 s on
    printed = format_summary(s)
    assert "LOST              board lost at t=5.2" in printed and "stale" in printed
    assert "outage t    5.2" in printed and "not back" in printed
    blind = _blind_rows_are_empty(tel)
    assert np.all(blind[tel["t"] > 5.3])
    assert _first(events, "lost")["why"] == s["lost"]


def test_hil_run_exits_3_when_the_board_is_lost(tmp_path):
    scenario = tmp_path / "stalled.toml"
    text = (ROOT / "fixtures" / "scenarios" / "cubesat-1u.toml").read_text()
    scenario.write_text(text.replace("[faults]\n", '[faults]\nstall = ["4.0:100"]\n'))
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--scenario", str(scenario), "--recover-within", "1.5",
         "--no-plots", "--out", str(tmp_path / "runs")],
        capture_output=True, text=True, timeout=180,
    )  # fmt: skip
    assert done.returncode == EXIT_LOST, done.stderr
    assert "exit              lost: board lost at t=4.2" in done.stdout
    assert "LOST" in done.stdout and "fault  t    4.2" in done.stdout


def test_a_phone_gap_holds_the_gimbals_and_the_still_window_comes_again(tmp_path):
    """The phone pauses its stream for 1 s mid-slew: the host notices within the bound, holds (gimbal-rate
    commands zero) rather than steer on an estimate that no longer moves, and when samples flow again
    waits a still window for the estimate before it slews anew."""
    result, tel, events = _run(tmp_path, _quick(phone_gap=["4.0:1.0"]), duration_s=14.0)
    s = result.summary
    assert s["exit"] == "completed" and s["phone_gaps"] == 1 and s["failsafe_events"] == 0
    gap = _first(events, "phone_gap")
    assert 4.0 + 0.2 < gap["t"] <= 4.0 + 0.25 + 2 * DT
    back = _first(events, "phone_back")
    assert back["t"] == pytest.approx(5.0, abs=2 * DT)
    still = _first(events, "still_window", after=back["t"] - 1e-9)
    resume = _first(events, "resume", after=still["t"])
    assert resume["t"] - still["t"] >= 2.0 - 1e-9  # the warm-up's still window
    t = tel["t"]
    held = (t >= gap["t"] - 1e-9) & (t < resume["t"] - 1e-9)
    assert np.all(tel["cmd_gimbal_rate_0"][held] == 0.0) and np.all(tel["phase"][held] == 0)
    assert np.all(tel["phone_age_ms"][(t > gap["t"]) & (t < back["t"] - 1e-9)] > 250.0)
    assert s["phone_gap_list"][0]["recovered"] and s["phone_gap_list"][0]["causes"] == ["phone_gap"]
    assert not np.any(tel["board_link"][tel["t"] > 0.5] != 0)  # the board was live all along


def test_the_operators_disarm_wins_over_the_hosts_rearm(tmp_path):
    """The ground station's finding: a Disarm from the page while the board failed safe used to be
    undone by the host's own re-arm. The operator disarms during a link stall (before the host hears of
    the failsafe): the board ends disarmed, and the host never re-arms it."""

    class Operator(SilentObserver):
        host = None
        done = False

        def started(self, start):
            self.host = start.host

        def tick(self, t):
            if not self.done and t >= 6.1:
                self.done = True
                self.host.disarm(t)

    result, tel, events = _run(tmp_path, _quick(stall=["6.0:0.4"]), duration_s=8.0, observer=Operator())
    s = result.summary
    assert s["failsafe_events"] == 1 and s["rearms"] == 0
    assert not any(e["kind"] == "rearmed" for e in events)
    states = [e["new"] for e in events if e["kind"] == "board_state" and e["t"] > 6.0]
    assert "FAILSAFE" in states and states[-1] == "DISARMED" and "ARMED" not in states
    assert tel["board_state"][-1] == int(BoardState.DISARMED)
    # the operator's disarm is not an outage, and a run left disarmed by the operator did not complete
    assert s["lost"] is None and s["outages"][-1]["recovered"]
    assert s["exit"].startswith("disarmed by the operator at t=6.1") and s["suspended_at_end"] >= 6.1


def test_a_disarm_cancels_a_rearm_already_pending(tmp_path):
    """The re-arm the host wants after a failsafe, still pending (not sent yet) when the operator disarms:
    cancelled, logged, and the board is disarmed."""
    from hil.runtime.faults import FaultJournal
    from hil.runtime.watch import BoardWatch

    clock = LockstepClock()
    with BoardClient("emu://?units=4", clock=clock) as client:
        client.arm()
        events = EventLog(tmp_path / "events.jsonl")
        watch = BoardWatch(client, events, FaultJournal(), 0.25)
        watch.on_events([StateEvent(clock.now(), BoardState.ARMED, BoardState.FAILSAFE)])
        assert watch.rearm_pending and watch.take_upsets() == ["failsafe"]
        cmd = watch.operator_disarm(clock.now())
        assert not watch.rearm_pending
        client.wait(cmd)
        watch.rearm_if_needed(clock.now())  # nothing to send
        assert client.state is BoardState.DISARMED and client.stats().counters.frames_out > 0
        events.close()
    records = read_events(tmp_path / "events.jsonl")[0]
    assert [r["kind"] for r in records] == ["board_state", "rearm_cancelled"]


# ----------------------------------------------------------------------------------------- finding 7
def test_a_wall_clock_run_loads_its_kernels_before_it_arms(monkeypatch, tmp_path):
    """Finding 7: the real-time host stalled on its compiled kernels' first calls (loaded from numba's
    cache, 0.35-0.7 s) inside the control task, after arming. The run now loads them first."""
    from hil.runtime import warmup

    order: list[str] = []
    warm_host, arm = warmup.warm_host, BoardClient.arm
    monkeypatch.setattr(warmup, "_LOADED", set())  # as in a fresh process (loaded once per process)
    monkeypatch.setattr(warmup, "warm_host", lambda sc: (order.append("kernels"), warm_host(sc))[1])
    monkeypatch.setattr(BoardClient, "arm", lambda self, *a: (order.append("arm"), arm(self, *a))[1])
    result = run(_quick(), RunOptions(lockstep=False, out_root=tmp_path, duration_s=0.2))
    assert result.summary["mode"] == "realtime" and order == ["kernels", "arm"]


def test_the_host_kernels_loaded_before_arming_are_all_the_run_calls():
    """warm_host calls every host kernel with the run's argument types: a lockstep run after it (world
    kernels aside) compiles or loads no host kernel signature of its own."""
    code = r"""
import sys
from hil.jit import Kernel
from hil.scenario import load_scenario
from hil.runtime.warmup import warm_host
from hil.runtime import RunOptions, run

def host_kernels():
    out = {}
    for name, module in list(sys.modules.items()):
        if name.startswith(("hil.estimation", "hil.control", "hil.so3")):
            for attr, value in vars(module).items():
                if isinstance(value, Kernel) and value.versions:
                    out[f"{name}.{attr}"] = value.versions
    return out

sc = load_scenario("cubesat-1u")
warm_host(sc)
before = host_kernels()
run(sc, RunOptions(out_root=None, duration_s=0.5))
after = host_kernels()
grown = {k: (before.get(k, 0), v) for k, v in after.items() if v > before.get(k, 0)}
print(len(before), grown)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    count, grown = done.stdout.split(" ", 1)
    assert int(count) >= 4 and grown.strip() == "{}"  # steering's three, the filter chain's step


# ----------------------------------------------------------------------------------------- real time
def _follow(run_root: Path, kind: str, timeout: float, after: float = -np.inf) -> dict:
    """The first ``kind`` record after ``after`` in the run's events.jsonl, waiting for it."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for path in run_root.glob("*/events.jsonl"):
            for line in path.read_text().splitlines():
                try:
                    e = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if e["kind"] == kind and e["t"] > after:
                    return e
        time.sleep(0.05)
    raise AssertionError(f"no {kind!r} event within {timeout} s")


def _board(link: Path, phone: str) -> subprocess.Popen:
    sim = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--world", "cubesat-1u", "--link", str(link),
         "--phone", phone],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    assert sim.stdout is not None and sim.stdout.readline().startswith("/dev/pts/")
    return sim


def test_a_board_killed_mid_slew_and_restarted_is_recovered(tmp_path, phone_port):
    """Finding 1 as a user found it: firmware-sim --world on a pty, `hil run --port` against it, the board
    killed with SIGKILL during the slew and started again. The host reports the link loss, the new
    board's reset (POWER_ON) and its phone's new clock, re-arms after the handshake, warms up (the new
    board's rotors are stopped: steering them was the singular matrix) and slews again: exit 0."""
    link, phone = tmp_path / "board", f"udp://127.0.0.1:{phone_port}"
    runs = tmp_path / "runs"
    sim = _board(link, phone)
    host = subprocess.Popen(
        [sys.executable, "-m", "hil", "run", "--port", str(link), "--phone", phone, "--duration", "14",
         "--no-plots", "--out", str(runs)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    again = None
    try:
        _follow(runs, "slew_start", 60)
        time.sleep(1.0)
        sim.send_signal(signal.SIGKILL)
        sim.wait()
        time.sleep(1.0)
        again = _board(link, phone)
        out, err = host.communicate(timeout=90)
    finally:
        for p in (host, sim, again):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()
    assert host.returncode == 0, err
    assert "Traceback" not in err
    s = json.loads(next(runs.glob("*/summary.json")).read_text())
    assert s["exit"] == "completed" and s["lost"] is None
    # One loss (the kill) — and, on a machine where other processes make ptys, the pty number the link
    # pointed at may be reused by another process's board while ours restarts: reached first, refused as
    # another board (or gone again with its owner), each a loss of its own, then ours again.
    assert s["link_lost"] >= 1 and s["reconnects"] >= 1 and s["board_resets"] >= 1
    reset = next(f for f in s["faults"] if f["kind"] == "reset")
    assert reset["cause"] == "POWER_ON"
    assert any(f["kind"] == "phone_restart" for f in s["faults"])
    outage = s["outages"][-1]
    assert outage["recovered"] and {"link_lost", "reset", "reconnect"} <= set(outage["causes"])
    events = read_events(next(runs.glob("*/events.jsonl")))[0]
    lost = _first(events, "link_lost")
    rearmed = _first(events, "rearmed", after=lost["t"])
    resume = _first(events, "resume", after=rearmed["t"])
    assert _first(events, "board_reset")["t"] <= rearmed["t"]  # armed again only after the handshake
    tel = read_telemetry(next(runs.glob("*/telemetry.csv")))
    blind = _blind_rows_are_empty(tel)
    t = tel["t"]
    gone = (t > lost["t"]) & (t < reset_t(events))
    assert gone.sum() > 20 and np.all(blind[gone]) and np.all(tel["board_link"][gone] == int(BoardLink.LOST))
    assert np.all(np.diff(tel["tel_age_ms"][gone]) > 0)
    assert np.all(tel["phase"][(t > lost["t"]) & (t < resume["t"] - 1e-9)] == 0)
    assert "reset            " not in out and "fault  t" in out and "POWER_ON" in out  # printed, with cause


def reset_t(events) -> float:
    return _first(events, "board_reset")["t"]


def test_a_board_killed_for_good_ends_the_run_lost_with_exit_3(tmp_path, phone_port):
    """Finding 3 as a user found it: the board killed 2 s into the slew and never started again. The host
    does not "control" it for the rest of the run: 3 s later (--recover-within 3) the run ends, exit status
    3, and the printed summary says the link was lost, when, and for how long."""
    link, phone = tmp_path / "board", f"udp://127.0.0.1:{phone_port}"
    runs = tmp_path / "runs"
    sim = _board(link, phone)
    host = subprocess.Popen(
        [sys.executable, "-m", "hil", "run", "--port", str(link), "--phone", phone, "--duration", "30",
         "--recover-within", "3", "--no-plots", "--out", str(runs)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        _follow(runs, "slew_start", 60)
        time.sleep(2.0)
        sim.send_signal(signal.SIGKILL)
        sim.wait()
        killed = time.monotonic()
        out, err = host.communicate(timeout=60)
        ended = time.monotonic()
    finally:
        for p in (host, sim):
            if p.poll() is None:
                p.kill()
                p.wait()
    assert host.returncode == EXIT_LOST, err
    assert ended - killed < 3.0 + 5.0  # the bound, then the summary (not the 28 s the run had left)
    s = json.loads(next(runs.glob("*/summary.json")).read_text())
    assert s["exit"].startswith("lost: board lost at t=") and "link_lost" in s["exit"]
    assert s["outages"][-1]["recovered"] is False and s["outages"][-1]["duration_s"] >= 3.0
    assert "LOST              board lost" in out and "link_lost" in out and "not back" in out
    tel = read_telemetry(next(runs.glob("*/telemetry.csv")))
    lost = s["outages"][-1]["start"]
    after = tel["t"] > lost + 1e-9
    assert after.sum() > 100 and np.all(tel["board_link"][after] == int(BoardLink.LOST))
    _blind_rows_are_empty(tel)
