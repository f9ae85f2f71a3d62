"""The fault soak's real-time part: ``hil run --port`` (the host, in a thread of this process, its run
observer timestamping everything) against ``firmware-sim --world`` on a pty or on a CAN bus
(``udp_multicast``, classic CAN or CAN FD), the world's phone reaching the host through
:class:`bench.soak_phone.PhoneRelay`; faults one after the other, each once the host steers again: the
board killed with SIGKILL and started again (``kill``), frozen with SIGSTOP and let go (``freeze``: a
stalled board), the phone paused (``phone_pause``), hostile datagrams to the host's phone port
(``hostile``), and on a bus, a noisy node sending damaged segments under the board's and the host's
arbitration ids (``noise``). See :mod:`bench.soak`.
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

from bench.bench_runtime import _free_port
from bench.soak import (
    BACK_S,
    FREEZE_S,
    NOISE_HZ,
    NOISE_S,
    PAUSE_S,
    RECOVER_WITHIN_S,
    RESTART_S,
    SCENARIO,
    STEER_S,
    Cycle,
    Recorder,
    check_logs,
    check_outages,
    check_recovery,
)
from bench.soak_phone import PhoneRelay, hostile_datagrams, send
from hil.runtime import RunOptions, run
from hil.scenario import load_scenario

START_S = 90.0  # firmware-sim's world and the host's first slew, at most (a loaded machine)
HOSTILE_WATCH_S = 1.5  # after a hostile burst: nothing may happen for this long
RELAY_DRAIN_S = 0.5  # s: the relay's last datagrams, read by the host before the soak ends its run
HOSTILE_REPEAT = 5  # each hostile datagram sent this many times a cycle


TARGETS = ("python", "avr", "can", "can-fd")
"""The boards the real-time soak serves: the Python emulator with its world (``firmware-sim --world``,
its phone the world's) on a pty, or on a ``udp_multicast`` CAN bus (``can``: classic CAN, ``can-fd``), or
the C firmware on simavr (``firmware-sim --avr``, its units the firmware's own open-loop estimates; the
phone a still stand-in streaming from its own process) on a pty."""
BUS_TARGETS = ("can", "can-fd")


def _board(link: Path | str, phone_url: str, target: str = "python") -> subprocess.Popen[str]:
    """firmware-sim serving ``target`` on the pty ``link`` (a path) or the bus ``link`` (a ``can://``
    URL), started and answering."""
    if target in BUS_TARGETS:
        options = ["--world", SCENARIO, "--phone", phone_url, "--can", str(link)]
    elif target == "python":
        options = ["--link", str(link), "--world", SCENARIO, "--phone", phone_url]
    else:
        options = [
            "--link",
            str(link),
            "--avr",
            *(a for a in load_scenario(SCENARIO).firmware_sim_argv() if not a.startswith("--units=")),
        ]  # the board options, not --units
    errors = tempfile.TemporaryFile(mode="w+")  # what it says if it does not start (kept by the OS)
    sim = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", *options],
        stdout=subprocess.PIPE,
        stderr=errors,
        text=True,
    )
    assert sim.stdout is not None
    first = sim.stdout.readline()
    if not first.startswith(("/dev/pts/", "can://")):
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
    """The faults of ``plan`` (``kill``, ``freeze``, ``kill_harness`` with the firmware, ``phone_pause``,
    ``hostile``, ``second_host`` on a pty, ``noise`` on a bus) in one real-time run against ``target``
    (:data:`TARGETS`), each at a drawn moment: the first from the run's start, the next ones after the
    host is back in control (see :mod:`bench.soak`)."""
    from contextlib import ExitStack

    from bench.bench_runtime import _still_phone

    rng = np.random.default_rng([seed, 7])
    scenario = load_scenario(SCENARIO)
    port = _free_port(socket.SOCK_DGRAM)
    relay = PhoneRelay(("127.0.0.1", port)).start()
    out_root.mkdir(parents=True, exist_ok=True)
    link: Path | str = out_root / "board"
    if target in BUS_TARGETS:
        from bench.can_bus import multicast_url

        link = multicast_url(fd=target == "can-fd")
    stack = ExitStack()
    if target == "avr":
        stack.enter_context(_still_phone(relay.url))
    sims = [_board(link, relay.url, target)]
    mode = {"python": "pty"}.get(target, target)
    rec = Recorder(scenario.n_units)
    noise_counted: dict[int, int] = {}  # cycle number -> damaged CAN frames the host counted in its noise
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

        def ready() -> bool:
            """Armed (in the run's set-up) and ticking (the recorder knows the host's clock, on which the
            first fault's moment is drawn: the first tick comes after the Arm), or ended."""
            armed = rec.first("armed", -1.0) is not None
            return (armed and rec.offset is not None) or not thread.is_alive()

        if not _wait(ready, START_S):
            raise RuntimeError("the host did not arm the board")
        if rec.offset is None:  # the host's run ended before its loop ticked
            raise RuntimeError(f"the host's run ended before it began: {outcome}")
        start = rec.now()
        for n, kind in enumerate(plan):
            lo, hi = FIRST_WINDOW_S if n == 0 else NEXT_WINDOW_S
            at = (start if n == 0 else rec.now()) + float(rng.uniform(lo, hi))
            _wait(lambda at=at: rec.now() >= at or not thread.is_alive(), hi + 1.0)
            if not thread.is_alive():
                cycles.append(Cycle(kind, mode, rec.now(), problems=[f"the host stopped: {outcome}"]))
                continue
            c = Cycle(kind, mode, rec.now())
            if kind == "freeze":
                sims[-1].send_signal(signal.SIGSTOP)
                time.sleep(FREEZE_S)
                sims[-1].send_signal(signal.SIGCONT)
            elif kind == "noise":
                before = _damaged(rec)
                _bus_noise(str(link), rng)
                time.sleep(0.3)  # the host's reader has taken what the noise left on the bus
                noise_counted[len(cycles)] = _damaged(rec) - before
            elif kind in ("kill", "kill_harness"):
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
                send(datagrams, ("127.0.0.1", port), HOSTILE_REPEAT, relay.out)  # as the phone
                hostile_bad += bad * HOSTILE_REPEAT
            cycles.append(c)
            if kind == "noise":
                _wait(lambda: rec.start is not None and rec.start.host.in_control, BACK_S[mode])
            elif kind in ("hostile", "second_host"):
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
    _after(cycles, rec, outcome, thread, relay, hostile_bad, noise_counted)
    return cycles


def _damaged(rec: Recorder) -> int:
    """CAN frames the host's transport found damaged and discarded so far (incomplete, spliced,
    malformed: :meth:`hil.link.transports.can_bus.CanTransport.counters`)."""
    start = rec.start
    if start is None:
        return 0
    counters = start.host.client.transport.counters()  # type: ignore[attr-defined]  # a CanTransport
    return int(counters["rx_incomplete"] + counters["rx_spliced"] + counters["rx_malformed"])


def _bus_noise(url: str, rng: np.random.Generator) -> None:
    """A noisy node on the bus ``url`` for ``NOISE_S`` s: ``NOISE_HZ`` CAN frames a second under the
    board's and the host's arbitration ids (every priority), each a segment with a drawn transfer id and
    index and drawn bytes — damaged segments, as a failing transceiver or a node with a wrong bit timing
    puts on a bus."""
    import can

    from hil.link.transports.can_bus import CanTransport
    from protocol.can import CanId, Direction, Priority

    bus = CanTransport(url)  # for its parsed options only (interface, channel, node, fd, port)
    ids = [CanId(p, d, bus.node).value for p in Priority for d in Direction]
    size = 64 if bus.fd else 8
    with can.Bus(interface=bus.interface, channel=bus.channel, fd=bus.fd, **bus._bus_options) as noisy:
        end = time.monotonic() + NOISE_S
        while time.monotonic() < end:
            data = bytes(rng.integers(0, 256, int(rng.integers(2, size + 1)), dtype=np.uint8))
            noisy.send(can.Message(arbitration_id=int(rng.choice(ids)), data=data, is_fd=bus.fd,
                                   is_extended_id=False))  # fmt: skip
            time.sleep(1.0 / NOISE_HZ)


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


def _second_host(c: Cycle, link: Path | str) -> None:
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
           relay: PhoneRelay, hostile_bad: int, noise_counted: dict[int, int]) -> None:  # fmt: skip
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
        if c.kind == "noise":
            _check_noise(c, rec, noise_counted.get(i, 0), end, faults)
        elif c.kind not in ("hostile", "second_host") and not c.problems:  # those two: _check_hostile
            check_recovery(c, rec, end, c.mode, faults)
        c.problems += problems


def _check_noise(c: Cycle, rec: Recorder, counted: int, end: float, faults: list[dict[str, Any]]) -> None:
    """A noisy node on the bus: the damaged frames counted (the fault detected), every outage it caused
    over within its bound, no stale row."""
    if counted <= 0:
        c.problems.append("no damaged CAN frame counted by the host")
    c.cause = f"{counted} damaged CAN frames counted"
    check_outages(c, rec, end, faults)
