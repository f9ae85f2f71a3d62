"""The fault soak's real-time part: ``hil run --port`` (the host, in a thread of this process, its run
observer timestamping everything) against ``firmware-sim --world`` on a pty, the world's phone reaching
the host through :class:`bench.soak_phone.PhoneRelay`; faults one after the other, each once the host steers
again: the board killed with SIGKILL and started again (``kill``), the phone paused (``phone_pause``),
hostile datagrams to the host's phone port (``hostile``). See :mod:`bench.soak`.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.soak import (
    BACK_S,
    PAUSE_S,
    RECOVER_WITHIN_S,
    RESTART_S,
    SCENARIO,
    STEER_S,
    Cycle,
    Recorder,
    check_logs,
    check_recovery,
)
from bench.soak_phone import PhoneRelay, hostile_datagrams, send
from hil.runtime import RunOptions, run
from hil.scenario import load_scenario

START_S = 90.0  # firmware-sim's world and the host's first slew, at most (a loaded machine)
HOSTILE_WATCH_S = 1.5  # after a hostile burst: nothing may happen for this long
RELAY_DRAIN_S = 0.5  # s: the relay's last datagrams, read by the host before the soak ends its run
HOSTILE_REPEAT = 5  # each hostile datagram sent this many times a cycle


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


TARGETS = ("python", "avr")
"""The boards the real-time soak serves: the Python emulator with its world (``firmware-sim --world``,
its phone the world's), or the C firmware on simavr (``firmware-sim --avr``, its units the firmware's own
open-loop estimates; the phone a still stand-in streaming from its own process)."""


def _board(link: Path, phone_url: str, target: str = "python") -> subprocess.Popen[str]:
    if target == "python":
        options = ["--world", SCENARIO, "--phone", phone_url]
    else:
        options = [
            "--avr",
            *load_scenario(SCENARIO).firmware_sim_argv()[2:],
        ]  # the board options, not --units
    errors = tempfile.TemporaryFile(mode="w+")  # what it says if it does not start (kept by the OS)
    sim = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--link", str(link), *options],
        stdout=subprocess.PIPE,
        stderr=errors,
        text=True,
    )
    assert sim.stdout is not None
    first = sim.stdout.readline()
    if not first.startswith("/dev/pts/"):
        sim.kill()
        sim.wait()
        errors.seek(0)
        said = (first + errors.read())[-2000:]
        raise RuntimeError(f"firmware-sim did not start (exit {sim.returncode}): {said}")
    return sim


def _harness_of(sim: subprocess.Popen[str]) -> int | None:
    """The pid of ``firmware-sim --avr``'s harness (its child), if it runs."""
    children = Path(f"/proc/{sim.pid}/task/{sim.pid}/children")
    try:
        pids = [int(p) for p in children.read_text().split()]
    except (OSError, ValueError):
        return None
    return pids[0] if pids else None


def _wait(predicate: Any, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return False


FIRST_WINDOW_S = (0.2, 8.0)  # the first fault: from the run's start (handshake, still window, spin-up, slew)
NEXT_WINDOW_S = (0.0, 8.0)  # each next one: after the host has the board back (recovery warm-up, slew)


def pty_soak(plan: list[str], out_root: Path, seed: int = 0, target: str = "python") -> list[Cycle]:
    """The faults of ``plan`` (``kill``, ``kill_harness`` with the firmware, ``phone_pause``, ``hostile``,
    ``second_host``) in one real-time run against ``target`` (:data:`TARGETS`), each at a drawn moment:
    the first from the run's start, the next ones after the host is back in control (see
    :mod:`bench.soak`)."""
    from contextlib import ExitStack

    from bench.bench_runtime import _still_phone

    rng = np.random.default_rng([seed, 7])
    scenario = load_scenario(SCENARIO)
    port = _free_udp_port()
    relay = PhoneRelay(("127.0.0.1", port)).start()
    link = out_root / "board"
    out_root.mkdir(parents=True, exist_ok=True)
    stack = ExitStack()
    if target == "avr":
        stack.enter_context(_still_phone(relay.url))
    sims = [_board(link, relay.url, target)]
    mode = "pty" if target == "python" else "avr"
    rec = Recorder(scenario.n_units)
    outcome: dict[str, Any] = {}

    def host() -> None:
        try:
            outcome["result"] = run(scenario, RunOptions(
                port=str(link), phone=f"udp://127.0.0.1:{port}", duration_s=3_600.0, out_root=out_root,
                observer=rec, recover_within_s=RECOVER_WITHIN_S,
            ))  # fmt: skip
        except BaseException as exc:  # noqa: BLE001 - a crash is what the soak looks for
            outcome["error"] = exc

    thread = threading.Thread(target=host, name="soak-host", daemon=True)
    thread.start()
    cycles: list[Cycle] = []
    hostile_bad = 0
    try:
        if not _wait(lambda: rec.first("armed", -1.0) is not None or not thread.is_alive(), START_S):
            raise RuntimeError("the host did not arm the board")
        start = rec.now()
        for n, kind in enumerate(plan):
            lo, hi = FIRST_WINDOW_S if n == 0 else NEXT_WINDOW_S
            at = (start if n == 0 else rec.now()) + float(rng.uniform(lo, hi))
            _wait(lambda at=at: rec.now() >= at or not thread.is_alive(), hi + 1.0)
            if not thread.is_alive():
                cycles.append(Cycle(kind, mode, rec.now(), problems=[f"the host stopped: {outcome}"]))
                continue
            c = Cycle(kind, mode, rec.now())
            if kind in ("kill", "kill_harness"):
                if kind == "kill":
                    sims[-1].send_signal(signal.SIGKILL)
                    sims[-1].wait()
                else:
                    _kill_harness(c, sims[-1])
                time.sleep(float(rng.uniform(*RESTART_S)))  # started again a drawn while later
                sims.append(_board(link, relay.url, target))
            elif kind == "phone_pause":
                relay.pause(PAUSE_S)
            elif kind == "second_host":
                _second_host(c, link)
            else:
                datagrams, bad = hostile_datagrams(relay.newest_ns)
                send(datagrams, ("127.0.0.1", port), HOSTILE_REPEAT)
                hostile_bad += bad * HOSTILE_REPEAT
            cycles.append(c)
            if kind in ("hostile", "second_host"):
                time.sleep(HOSTILE_WATCH_S)
                _check_hostile(c, rec)
            elif not _wait(lambda c=c: rec.steering(c.t_fault) is not None, STEER_S[mode] + 2.0):
                c.problems.append(f"not steering again within {STEER_S[mode] + 2.0} s (a hang?)")
            _wait(lambda: rec.start is not None and rec.start.host.in_control, BACK_S[mode])
    finally:
        relay.stop_forwarding()
        time.sleep(RELAY_DRAIN_S)  # the host reads what is on its way before it is told to stop
        rec.abort = "soak done"
        thread.join(timeout=60.0)
        stack.close()
        for sim in sims:
            if sim.poll() is None:
                sim.send_signal(signal.SIGINT)
                try:
                    sim.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    sim.kill()
                    sim.wait()
        relay.close()
    _after(cycles, rec, outcome, thread, relay, hostile_bad)
    return cycles


def _kill_harness(c: Cycle, sim: subprocess.Popen[str]) -> None:
    """SIGKILL the firmware's harness under ``firmware-sim --avr`` (issue 25, finding 5): firmware-sim
    must notice at once, say so and exit non-zero, leaving no board serving the pty."""
    harness = _harness_of(sim)
    if harness is None:
        c.problems.append("no avr-harness under firmware-sim to kill")
        return
    os.kill(harness, signal.SIGKILL)
    try:
        status = sim.wait(timeout=10.0)
    except subprocess.TimeoutExpired:
        c.problems.append("firmware-sim kept running after its harness died")
        sim.kill()
        sim.wait()
        return
    if status == 0:
        c.problems.append("firmware-sim exited 0 after its harness died")


def _second_host(c: Cycle, link: Path) -> None:
    """Another host tries the board's port while the run holds it (issue 25, finding 4): refused at once,
    the refusal naming the holder; the run's host must notice nothing (:func:`_check_hostile`)."""
    from hil.link.board import BoardClient
    from protocol.errors import PortBusy

    try:
        with BoardClient(str(link)) as intruder:
            intruder.connect(timeout=2.0)
    except PortBusy as exc:
        c.cause = f"refused: {exc.holder_pid is not None and 'holder named' or 'holder unknown'}"
        return
    except Exception as exc:  # noqa: BLE001 - any other outcome is the finding
        c.problems.append(f"the second host was not refused as busy: {exc!r}")
        return
    c.problems.append("a second host connected to the board the run holds")


def _check_hostile(c: Cycle, rec: Recorder) -> None:
    """Nothing happened: no fault, no phone gap or restart, the host in control all along."""
    c.cause = c.cause or "counted"
    upsets = (
        "phone_gap",
        "phone_restart",
        "phone_jump",
        "link_lost",
        "board_reset",
        "lost",
        "recovery_start",
    )
    faults = [e for e in rec.events if e["t"] >= c.t_fault and e["kind"] in upsets]
    if faults:
        c.problems.append(f"hostile datagrams made a {faults[0]['kind']}")
    if c.kind == "hostile":
        dropped = {e["reason"] for e in rec.events if e["t"] >= c.t_fault and e["kind"] == "readings_dropped"}
        if not {"out_of_range", "future"} <= dropped:  # the readable but absurd ones: dropped, counted
            c.problems.append(f"the absurd readings were not dropped and counted (reasons seen: {dropped})")
    if rec.start is None or not rec.start.host.in_control:
        c.problems.append("the host is not in control after hostile datagrams")


def _after(cycles: list[Cycle], rec: Recorder, outcome: dict[str, Any], thread: threading.Thread,
           relay: PhoneRelay, hostile_bad: int) -> None:  # fmt: skip
    """The run-level checks (the run ended as told, nothing logged lost, every datagram counted) and each
    recovering cycle's checks, once every event is in."""
    problems: list[str] = []
    if thread.is_alive():
        problems.append("the host did not end when told (a hang)")
    if "error" in outcome:
        problems.append(f"the run failed: {outcome['error']!r}")
    result = outcome.get("result")
    summary = rec.summary
    if result is not None:
        if not str(summary.get("exit", "")).startswith("aborted: soak done"):
            problems.append(f"exit {summary.get('exit')!r}")
        problems += check_logs(result.run_dir, rec, summary, lockstep=False)
        phone = summary.get("phone", {})
        # Every datagram read, refused or dropped by the kernel for want of buffer (counted, logged).
        counted = phone.get("messages", 0) + phone.get("bad_messages", 0) + phone.get("kernel_dropped", 0)
        if phone.get("bad_messages", 0) < hostile_bad or counted < relay.forwarded:
            problems.append(
                f"the phone receiver counted {phone.get('messages')} + {phone.get('bad_messages')} + "
                f"{phone.get('kernel_dropped')} (kernel) datagrams for {relay.forwarded} forwarded and "
                f"{hostile_bad} hostile"
            )
    faults = summary.get("faults", [])
    for i, c in enumerate(cycles):
        end = cycles[i + 1].t_fault if i + 1 < len(cycles) else float("inf")
        if c.kind not in ("hostile", "second_host") and not c.problems:  # those two: _check_hostile
            check_recovery(c, rec, end, c.mode, faults)
        c.problems += problems
