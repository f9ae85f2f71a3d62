"""Real time over each transport, in one run: the same board (``firmware-sim`` in its own process) behind a
pty and on a CAN bus (python-can's ``udp_multicast``, classic CAN and CAN FD), the same measurements on
each, every CAN figure next to the pty's measured in the same run (the pty is the peer: the link the
project was built on, and what a USB-serial board gives).

Per transport:

* **setpoint → pulse reported, p50 / p99** — a bare host (framer, deframer and the transport: no client)
  sends a setpoint and waits for the Telemetry showing the new gimbal pulse (490 Hz pulse frames, 1 kHz
  telemetry): :func:`bench.bench_firmware_sim.pulse_latency`;
* **setpoints sustained with 0 loss** — setpoint frames offered at rising rates on 1 ms deadlines; the
  highest rate the board decodes with at most 0.1 % lost (the board's own ``rx_frames``):
  :func:`bench.bench_firmware_sim.sustained_rate`;
* **a frame at this end's own node id** — CPU per received CAN frame of a second host at the host's node id,
  against another node's frame, 4096 sent segments remembered (:func:`same_node_cost`, virtual bus);
* **the closed loop** — ``hil run --port`` (its own process) against ``firmware-sim --world cubesat-1u``
  (the world's phone streaming to it): the host's control lateness p99 and overruns (``summary.json``),
  and the world's lag behind the board's clock after start-up, as firmware-sim reports it when stopped.

A machine without an IPv4 multicast route cannot carry ``udp_multicast``: the CAN rows are then left out
with that reason in a note, and the pty's are still measured.

    python -m bench transports [--quick]
"""

from __future__ import annotations

import json
import re
import signal
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.bench_firmware_sim import RATES, _pct, pulse_latency, sustained_rate
from bench.bench_runtime import _phone_url
from bench.can_bus import multicast_url, udp_multicast_problem
from bench.child import firmware_sim, started
from bench.common import Result
from hil.scenario import load_scenario

NAME = "transports"
SCENARIO = "cubesat-1u"
CAN_RATES = (500, 1_000, *RATES)
"""Setpoint frames/s offered on a bus (each frame is several CAN segments, each a UDP datagram here)."""

_WORLD_LINE = re.compile(
    r"started (?P<startup>\d+) ms behind the board's clock, then (?P<episodes>\d+) lag episode\(s\), "
    r"at most (?P<max>\d+) ms behind"
)


def closed_loop(duration_s: float, can: str | None) -> dict[str, float]:
    """``hil run --port`` against ``firmware-sim --world`` on a pty or on the bus ``can`` for
    ``duration_s`` s: control lateness p99 and max (µs), overruns, and the world's lag (ms) after
    start-up, with its episodes."""
    phone = _phone_url()
    with tempfile.TemporaryDirectory(prefix="bench-transports-") as tmp:
        link = Path(tmp) / "board"
        where = ["--can", can] if can is not None else ["--link", str(link)]
        with started(firmware_sim("--world", SCENARIO, "--phone", phone, *where), stop=signal.SIGINT) as sim:
            port = sim.first_line if can is not None else str(link)
            argv = [sys.executable, "-m", "hil", "run", "--port", port, "--phone", phone, "--duration",
                    str(duration_s), "--no-plots", "--out", tmp]  # fmt: skip
            done = subprocess.run(argv, capture_output=True, text=True, timeout=duration_s + 240, check=False)
        said = sim.said
        written = sorted(Path(tmp).glob("*/summary.json"))
        if not written:
            raise RuntimeError(f"hil run left no summary (exit {done.returncode}): {done.stderr[-999:]}")
        summary = json.loads(written[0].read_text())
    world = _WORLD_LINE.search(said)
    if world is None:
        raise RuntimeError(f"firmware-sim did not report its world's lag: {said[-999:]}")
    control = summary["tasks"]["control"]
    return {
        "lateness_p99_us": float(control["lateness_p99_us"]),
        "lateness_max_us": float(control["lateness_max_us"]),
        "overruns": float(control["overruns"]),
        "world_startup_ms": float(world["startup"]),
        "world_lag_max_ms": float(world["max"]),
        "world_episodes": float(world["episodes"]),
    }


def _measure(samples: int, seconds: float, duration_s: float, can: str | None) -> dict[str, float]:
    latency, lost = pulse_latency(samples, can)
    rate, note = sustained_rate(seconds, can, CAN_RATES if can is not None else RATES)
    loop = closed_loop(duration_s, can)
    return {
        "p50": statistics.median(latency),
        "p99": _pct(latency, 99),
        "lost": float(lost),
        "samples": float(len(latency)),
        "rate": rate,
        "rate_note": note,  # type: ignore[dict-item]
        **loop,
    }


def _rows(label: str, ours: dict[str, float], pty: dict[str, float]) -> list[Result]:
    peer = "pty, same run"
    rows = [
        Result(NAME, f"{label}: setpoint -> pulse reported p50", ours["p50"], "ms", peer, pty["p50"], False,
               f"{ours['samples']:.0f} samples, {ours['lost']:.0f} given up after 0.5 s"),
        Result(NAME, f"{label}: setpoint -> pulse reported p99", ours["p99"], "ms", peer, pty["p99"], False),
        Result(NAME, f"{label}: setpoints sustained (<= 0.1 % lost)", ours["rate"], "frames/s", peer,
               pty["rate"], True, str(ours["rate_note"])),
        Result(NAME, f"{label}: hil run control lateness p99", ours["lateness_p99_us"], "us", peer,
               pty["lateness_p99_us"], False, f"max {ours['lateness_max_us']:.0f} us, "
               f"{ours['overruns']:.0f} overruns"),
        Result(NAME, f"{label}: world lag after start-up, max", ours["world_lag_max_ms"], "ms", peer,
               pty["world_lag_max_ms"], False, f"{ours['world_episodes']:.0f} lag episode(s); started "
               f"{ours['world_startup_ms']:.0f} ms behind"),
    ]  # fmt: skip
    return rows


def same_node_cost(frames: int) -> dict[str, float]:
    """CPU µs a host's read spends per received CAN frame (python-can's ``virtual`` bus: no multicast
    needed), once the host has sent 4200 segments — more than the 4096 it remembers until their loopback
    comes back, which the virtual bus never sends —, for another node's frame and for a frame in the
    host's own direction and node id (a second host at its node id), which asks "is this one of ours?"
    under the writer's lock. They were ~5 against ~112 µs when that was a scan of the 4096."""
    import os
    import time

    import can

    from hil.link.transports.can_bus import CanTransport
    from protocol.can import CanId, Direction, Priority
    from protocol.frame import encode_frame
    from protocol.messages import ActuatorSetpoint, UnitSetpoint

    channel = f"bench-same-node-{os.getpid()}"
    out: dict[str, float] = {}
    with CanTransport(f"can://virtual/{channel}?node=5") as host:
        raw = can.Bus(interface="virtual", channel=channel)
        try:
            for i in range(700):
                host.write(encode_frame(ActuatorSetpoint(units=(UnitSetpoint(0.1, 300.0),) * 4), i & 0xFF))
            for name, node in (("other node", 6), ("same node", 5)):
                arb = CanId(Priority.CONTROL, Direction.TO_BOARD, node).value
                for k in range(frames):
                    raw.send(
                        can.Message(arbitration_id=arb, data=k.to_bytes(8, "little"), is_extended_id=False)
                    )
                goal = host.counters()["rx_ignored"] + frames
                start = time.process_time()
                while host.counters()["rx_ignored"] < goal:
                    host.read(0.0)
                out[name] = 1e6 * (time.process_time() - start) / frames
        finally:
            raw.shutdown()
    return out


def run(quick: bool) -> list[Result]:
    samples = 30 if quick else 300
    seconds = 0.5 if quick else 2.0
    duration_s = 12.0 if quick else load_scenario(SCENARIO).slew.duration_s
    cost = same_node_cost(5_000 if quick else 50_000)
    results = [
        Result(NAME, "CAN receive: a frame at this end's own node id, 4096 sent segments remembered",
               cost["same node"], "us/frame", "another node's frame", cost["other node"], False,
               "CPU time of the host's reads (virtual bus); was ~20x the peer with a linear search"),
    ]  # fmt: skip
    pty = _measure(samples, seconds, duration_s, None)
    results += _rows("pty", pty, pty)
    problem = udp_multicast_problem()
    if problem is not None:
        results.append(Result(NAME, "CAN (udp_multicast)", float("nan"), "", "", None, False,
                              f"not measured: {problem}"))  # fmt: skip
        return results
    for label, fd in (("CAN classic", False), ("CAN FD", True)):
        results += _rows(label, _measure(samples, seconds, duration_s, multicast_url(fd)), pty)
    return results
