"""The host's runtime (:func:`hil.runtime.run`) end to end, each figure next to a peer measured in the same
run:

* **real-time control period jitter** p50 / p99 / max at 100 Hz and 200 Hz: the real runtime (board client,
  phone receiver, estimator and control tasks on :class:`hil.timing.scheduler.Scheduler`) in ``--port`` mode
  against ``spawn://firmware-sim`` on a real pty with its world (``cubesat-1u``), the world's simulated
  phone streaming to the host over loopback UDP as SensaGram does (firmware-sim's ``--phone udp://…``) to a
  free port the host listens on (``RunOptions.phone``). The board's pulse frame rate is twice the control
  rate (200 / 400 Hz). The figure is the scheduler's own lateness of each control activation after its
  absolute deadline (``summary["tasks"]["control"]``), over the whole run (warm-up, spin-up, slew), plus the
  control task's overrun count: an activation skipped because the one before ran past it leaves no lateness
  sample, so the percentiles alone would hide it.

  The world costs CPU: its 1 ms plant step (plant, drives, phone model, board step) is measured first
  (CPU s per simulated s, in the note). Where it needs more than ``WORLD_BUDGET`` — a slow or shared
  machine — ``firmware-sim --world`` cannot keep real time: its world falls further and further behind
  the board's clock (the board keeps answering; the phone's samples come late and slow), which is not
  the run this figure describes. Then (and if a world run fails to start) the same
  runtime runs against ``spawn://firmware-sim`` *without* the world — the board's internal actuator
  model answers the pulses — with a stand-in phone in its own process (the scenario's phone model at
  rest, streamed in real time to the same URL); the rows then say ``no world``. The host does the same
  work per tick either way (its estimator, controller, steering and setpoint do not know what moves).

  Two peers, each run right after the runtime at the same rate for a few seconds:

  - a bare loop doing no work on the same :class:`~hil.timing.scheduler.Scheduler` and
    :class:`~hil.timing.clock.WallClock`, with the same lateness statistics: the floor this machine, its load
    and its timer give a Python loop — what the runtime adds on top of it is the runtime's own doing
    (the board link, serviced in the control task, the estimator task, the phone receiver's thread,
    the GIL they share);
  - a naive ``time.sleep(period)`` loop's period error ``|actual period - nominal|``: what a loop
    without absolute deadlines gets. Its errors also *accumulate*; the drift over the loop is in the
    note (the Scheduler's deadlines do not drift at all: ``origin + k * period``).

* **``hil run --port`` in its own process** (the command as a user types it, against
  ``spawn://firmware-sim`` with the still stand-in phone, the scenario's 50 Hz control, 3 s after the slew):
  its control task's worst lateness, overruns and the board's failsafes, from its ``summary.json``, next to
  a bare Scheduler loop at the same rate. A fresh process is the case the in-process figures above cannot
  show: there the benchmark's own process has loaded numba and its kernels before the run; a user's
  ``hil run`` loads them itself — before arming, since issue 16's finding 7 (a first kernel call inside the
  control task stalled it 0.35–0.7 s, past the board's link timeout).

* **host setpoint -> pulse change reported** p50 / p99 over the pty: measured by
  :func:`bench.bench_link._pty_latency` (the full client against ``spawn://firmware-sim``, 490 Hz frames,
  1 kHz telemetry) and emitted here too, next to the same raw pty echo peer — not re-implemented.

* **``hil run`` (the default scenario, cubesat-1u: 4 units, 1 ms plant step, 50 Hz control, ~38 s
  simulated), in lockstep through the full protocol** — the command a user types, in its own process:

  - simulated seconds per wall second of its run loop (``summary["loop_realtime_factor"]``: the scheduler
    running the world, estimator and control tasks — every setpoint and telemetry frame encoded, framed
    and decoded, the board emulated), next to the **world alone** (plant, drives, phone and board at idle,
    stepped as the runtime steps it, no host): what the host and the runtime add to the world's cost;
  - the whole command's wall time (interpreter start, imports, scenario, the run, the summary and the
    plots, drawn by a process started before the run), next to its run loop's own wall time;
  - the imports ``hil run`` needs before its first tick, next to a bare ``python -c pass``.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from urllib.parse import urlencode, urlsplit

import numpy as np

from bench.bench_firmware_sim import _pct
from bench.bench_link import _pty_latency
from bench.child import started
from bench.common import Result
from hil.scenario import Scenario, load_scenario
from hil.timing.clock import WallClock
from hil.timing.scheduler import PeriodicTask, Scheduler
from protocol.errors import HilError

NAME = "runtime"
SCENARIO = "cubesat-1u"
RATES = (100.0, 200.0)  # control rates (Hz); the board's pulse frame rate is twice that
FRAME_RATE_FACTOR = 2.0
WORLD_BUDGET = 0.7  # CPU s per simulated s above which firmware-sim --world cannot run in real time
WORLD_WARM_STEPS = 50  # plant steps before the world's cost is timed: the first loads its kernels
WORLD_COST_STEPS = 1000  # plant steps timed (1 simulated s at cubesat-1u's 1 ms)


# =========================================================================== real time, pty
@dataclass
class _Jitter:
    """One loop's lateness (or period error) statistics, µs."""

    p50: float
    p99: float
    max: float
    runs: int
    overruns: int = 0

    @classmethod
    def of(cls, samples_us: np.ndarray, overruns: int = 0) -> _Jitter:
        return cls(
            float(np.percentile(samples_us, 50)),
            float(np.percentile(samples_us, 99)),
            float(samples_us.max()),
            int(samples_us.size),
            overruns,
        )


def _free_port(kind: socket.SocketKind) -> int:
    """A port the kernel says is free now (bound to port 0, read, closed) for a TCP or UDP listener."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _phone_url() -> str:
    """Where the phone streams and the host listens: SensaGram's UDP on a free loopback port."""
    return f"udp://127.0.0.1:{_free_port(socket.SOCK_DGRAM)}"


def _at_rate(scenario: Scenario, rate_hz: float) -> Scenario:
    """``scenario`` with its control loop at ``rate_hz`` and the board's pulse frames faster still."""
    frame = FRAME_RATE_FACTOR * rate_hz
    return scenario.with_changes(
        loop=replace(scenario.loop, control_rate_hz=rate_hz, frame_rate_hz=frame),
        board_options={**scenario.board_options, "frame_rate": frame},
    )


def _world_cost() -> float:
    """CPU seconds the emulator's world (plant, drives, phone, board) needs per simulated second here: above
    ~0.7, ``firmware-sim --world`` cannot keep real time next to its board and pty server."""
    from firmware_sim.cli import build_parser, make_board
    from firmware_sim.world import World
    from hil.timing.clock import LockstepClock

    scenario = load_scenario(SCENARIO)
    clock = LockstepClock()
    world = World(scenario, make_board(build_parser().parse_args(["--units", "4"]), clock))

    def step(steps: int) -> None:
        for _ in range(steps):
            clock.advance(scenario.loop.plant_step_s)
            world.advance_to(clock.now())

    step(WORLD_WARM_STEPS)  # its kernels loaded (from numba's cache: ~0.15 s) before the clock starts
    cpu = time.process_time()
    step(WORLD_COST_STEPS)
    return (time.process_time() - cpu) / (WORLD_COST_STEPS * scenario.loop.plant_step_s)


# A stand-in for the world's phone: the scenario's phone model at rest at the start attitude, sampled in
# real time in its own process (as firmware-sim's world would be) and streamed to argv[2].
_STILL_PHONE = r"""
import signal, sys, time
import numpy as np
from firmware_sim.world.models import BodyPhone
from hil.scenario import load_scenario
from hil.link.sources import open_sender
scenario = load_scenario(sys.argv[1])
sender = open_sender(sys.argv[2])
phone = BodyPhone(scenario.phone, scenario.seed)
R, w = np.asarray(scenario.slew.R0, float), np.zeros(3)
step = max(sender.batch_s, 0.005)
stop = []
signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
print("streaming", flush=True)
start, t, k = time.monotonic(), 0.0, 0
while not stop:
    k += 1
    time.sleep(max(start + k * step - time.monotonic(), 0.0))
    now = time.monotonic() - start
    samples = phone.sample(t, R, w, now, R, w)
    t = now
    if samples:
        sender.send(samples)
sender.close()  # a clean end of the connection, as an app that stops streaming
"""


@contextmanager
def _still_phone(url: str) -> Iterator[None]:
    """The stand-in phone, streaming to ``url`` before the run starts."""
    with started([sys.executable, "-c", _STILL_PHONE, SCENARIO, url], ready="streaming"):
        yield


def _runtime_realtime(
    rate_hz: float, duration_s: float, world: bool, rt_priority: int | None = None
) -> tuple[_Jitter, str]:
    """The runtime against firmware-sim on a pty — with its world (``world``) or, when the world cannot
    keep real time here, on the board's internal actuator model with a still phone stand-in — its threads
    under SCHED_FIFO at ``rt_priority`` if given: (control lateness, note)."""
    from hil.runtime import RunOptions, run

    scenario = _at_rate(load_scenario(SCENARIO), rate_hz)
    phone = _phone_url()
    query = scenario.firmware_sim_options()
    if world:
        query += [("world", SCENARIO), ("phone", phone)]
    url = "spawn://firmware-sim?" + urlencode(query)
    with tempfile.TemporaryDirectory(prefix="bench-runtime-") as tmp, contextlib.ExitStack() as stack:
        if not world:
            stack.enter_context(_still_phone(phone))
        options = RunOptions(
            port=url, phone=phone, duration_s=duration_s, out_root=Path(tmp),
            label=f"bench-{rate_hz:.0f}hz", rt_priority=rt_priority,
        )  # fmt: skip
        note = ""
        try:  # the run stops the spawned firmware-sim itself (its transport's close), even on error
            summary = run(scenario, options).summary
        except Exception as exc:
            # The summary is written before the error is raised: its schedule statistics still count.
            written = sorted(Path(tmp).glob("*/summary.json"))
            summary = json.loads(written[0].read_text()) if written else {}
            if "control" not in summary.get("tasks", {}):
                raise
            note = f"run failed: {exc}; "
    control = summary["tasks"]["control"]
    jitter = _Jitter(
        control["lateness_p50_us"],
        control["lateness_p99_us"],
        control["lateness_max_us"],
        int(control["runs"]),
        int(control["overruns"]),
    )
    note += (
        f"{jitter.runs} control runs over {summary.get('wall_s', 0.0):.1f} s, exit {summary.get('exit')!r}, "
        f"{summary.get('failsafe_events')} failsafe events, {summary.get('phone_samples')} phone samples "
        f"({urlsplit(phone).scheme}), board frames {FRAME_RATE_FACTOR * rate_hz:.0f} Hz"
    )
    return jitter, note


def _scheduler_floor(rate_hz: float, seconds: float) -> _Jitter:
    """A task doing nothing on the runtime's Scheduler and WallClock: its lateness (µs)."""
    task = PeriodicTask("bare", 1.0 / rate_hz, lambda _due: None)
    scheduler = Scheduler(WallClock(), [task])
    scheduler.run(until=scheduler.origin + seconds)
    return _Jitter.of(task.stats.lateness * 1e6, task.stats.overruns)


def _sleep_loop(rate_hz: float, seconds: float) -> tuple[_Jitter, float]:
    """A ``time.sleep(period)`` loop: its period error |actual - nominal| (µs) and its drift (ms) at the end
    (how far the last wake-up is from ``start + n * period``)."""
    period = 1.0 / rate_hz
    n = max(int(seconds * rate_hz), 2)
    stamps = np.empty(n + 1)
    stamps[0] = time.monotonic()
    for k in range(1, n + 1):
        time.sleep(period)
        stamps[k] = time.monotonic()
    error_us = np.abs(np.diff(stamps) - period) * 1e6
    return _Jitter.of(error_us), (stamps[-1] - stamps[0] - n * period) * 1e3


def _jitter_results(rate_hz: float, duration_s: float, peer_s: float, world_note: str) -> list[Result]:
    """``world_note`` empty: the runtime against firmware-sim with its world; else why not (a stand-in)."""
    try:
        ours, note = _runtime_realtime(rate_hz, duration_s, world=not world_note)
    except HilError as exc:
        if world_note:
            raise
        world_note = f"firmware-sim --world failed ({exc}); "
        ours, note = _runtime_realtime(rate_hz, duration_s, world=False)
    if world_note:
        note = f"{world_note}no world: the board's internal actuator model, a still stand-in phone; {note}"
    floor = _scheduler_floor(rate_hz, peer_s)
    naive, drift_ms = _sleep_loop(rate_hz, peer_s)
    at = f"{rate_hz:.0f} Hz"
    where = "pty" if not world_note else "pty, no world"
    floor_note = (
        f"bare Scheduler loop: {floor.runs} runs, {floor.overruns} overruns; sleep(period) loop: "
        f"{naive.runs} periods, drifted {drift_ms:+.1f} ms (absolute deadlines: none)"
    )
    rows: list[Result] = []
    for stat in ("p50", "p99", "max"):
        figure = f"control jitter {stat} @{at} (runtime, {where})"
        rows += [
            Result(NAME, figure, getattr(ours, stat), "us", f"bare Scheduler loop {stat}",
                   getattr(floor, stat), False, note if stat == "p50" else ""),
            Result(NAME, figure, getattr(ours, stat), "us", f"sleep(period) period error {stat}",
                   getattr(naive, stat), False, floor_note if stat == "p50" else ""),
        ]  # fmt: skip
    rows.append(
        Result(NAME, f"control overruns @{at} (runtime, {where})", ours.overruns, "skipped",
               "bare Scheduler loop overruns", floor.overruns, False,
               f"of {ours.runs + ours.overruns} activations")
    )  # fmt: skip
    return rows


BUSY_RATE_HZ = 200.0
RT_PRIORITY = 20
"""The busy-core rows: the control rate, and the SCHED_FIFO priority of the run beside the normal one."""


@contextmanager
def _busy_core() -> Iterator[None]:
    """Another process keeping one core busy (a pure-Python spin, at the normal policy) while the block
    runs: what a second job, a browser or a campaign worker does to a real-time run on a small machine."""
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        yield
    finally:
        hog.kill()
        hog.wait()


def _listed(runs: list[_Jitter]) -> str:
    """Several runs' p99, max (µs) and overruns, in order, for a note."""
    p99 = ", ".join(f"{j.p99:.0f}" for j in runs)
    worst = ", ".join(f"{j.max:.0f}" for j in runs)
    return f"p99 {p99} µs, max {worst} µs, overruns {', '.join(str(j.overruns) for j in runs)}"


def _busy_results(duration_s: float, world_note: str) -> list[Result]:
    """The runtime at :data:`BUSY_RATE_HZ` against firmware-sim with a core busy beside it, at the normal
    policy and under ``SCHED_FIFO`` (``hil run --rt-priority``), alternated twice in one run; the better of
    each pair is not taken: both runs' worse p99 is reported, with both in the note."""
    from hil.timing.priority import realtime

    try:
        with realtime(RT_PRIORITY):
            pass
    except HilError as exc:
        return [Result(NAME, f"control lateness p99 @{BUSY_RATE_HZ:.0f} Hz, a core busy, SCHED_FIFO",
                       math.nan, "us", "normal policy", None, False, f"not measured: {exc}")]  # fmt: skip
    runs: dict[str, list[_Jitter]] = {"normal": [], "SCHED_FIFO": []}
    with _busy_core():
        for _ in range(2):
            for policy, priority in (("normal", None), ("SCHED_FIFO", RT_PRIORITY)):
                jitter, _ = _runtime_realtime(BUSY_RATE_HZ, duration_s, not world_note, priority)
                runs[policy].append(jitter)
    worst = {policy: max(js, key=lambda j: j.p99) for policy, js in runs.items()}
    said = "; ".join(f"{policy}: {_listed(js)}" for policy, js in runs.items())
    at = f"@{BUSY_RATE_HZ:.0f} Hz, a core busy"
    fifo, normal = worst["SCHED_FIFO"], worst["normal"]
    return [
        Result(NAME, f"control lateness p99 {at}, --rt-priority {RT_PRIORITY}", fifo.p99, "us",
               "normal policy, same run", normal.p99, False, said),
        Result(NAME, f"control overruns {at}, --rt-priority {RT_PRIORITY}", fifo.overruns, "skipped",
               "normal policy, same run", normal.overruns, False,
               f"of {fifo.runs + fifo.overruns} activations (the worse p99 run of two each)"),
    ]  # fmt: skip


def _cli_port_run(duration_s: float) -> tuple[dict, float]:
    """``hil run --port spawn://firmware-sim?... --phone udp://...`` in its own process with the still
    stand-in phone: (its control task's statistics, its failsafe events)."""
    scenario = load_scenario(SCENARIO)
    phone = _phone_url()
    url = "spawn://firmware-sim?" + urlencode(scenario.firmware_sim_options())
    with tempfile.TemporaryDirectory(prefix="bench-runtime-") as tmp, _still_phone(phone):
        argv = [sys.executable, "-m", "hil", "run", "--port", url, "--phone", phone, "--duration",
                str(duration_s), "--no-plots", "--out", tmp]  # fmt: skip
        done = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=False)
        written = sorted(Path(tmp).glob("*/summary.json"))
        if not written:
            why = done.stderr[-999:]
            raise RuntimeError(f"hil run --port left no summary (exit {done.returncode}): {why}")
        summary = json.loads(written[0].read_text())
    return summary["tasks"]["control"], float(summary.get("failsafe_events", 0))


def _cli_port_results(duration_s: float, peer_s: float) -> list[Result]:
    control, failsafes = _cli_port_run(duration_s)
    rate = load_scenario(SCENARIO).loop.control_rate_hz
    floor = _scheduler_floor(rate, peer_s)
    note = (f"{control['runs']} control runs, p99 {control['lateness_p99_us']:.0f} us; "
            f"bare loop {floor.runs} runs, {floor.overruns} overruns")  # fmt: skip
    return [
        Result(NAME, f"hil run --port, own process: control lateness max @{rate:.0f} Hz",
               control["lateness_max_us"], "us", "bare Scheduler loop max", floor.max, False, note),
        Result(NAME, "hil run --port, own process: control overruns", control["overruns"], "skipped",
               "bare Scheduler loop overruns", floor.overruns, False),
        Result(NAME, "hil run --port, own process: board failsafes", failsafes, "events", "", None, False,
               "a healthy board: any failsafe is the host's stall"),
    ]  # fmt: skip


def _latency_results(samples: int) -> list[Result]:
    latency, board_share, echo = _pty_latency(samples)
    note = (
        f"measured by bench_link._pty_latency ({samples} samples, 490 Hz frames, 1 kHz telemetry); "
        f"board share (telemetry link_age) p50 {statistics.median(board_share):.1f} ms"
    )
    return [
        Result(NAME, "setpoint -> pulse reported p50 (client, pty)", statistics.median(latency), "ms",
               "raw pty echo p50", statistics.median(echo), False, note),
        Result(NAME, "setpoint -> pulse reported p99 (client, pty)", _pct(latency, 99), "ms",
               "raw pty echo p99", _pct(echo, 99), False),
    ]  # fmt: skip


# =========================================================================== lockstep, `hil run`
def _hil_run(duration_s: float | None) -> tuple[float, dict]:
    """``python -m hil run`` (plots included) in its own process: (its wall time s, its summary.json)."""
    with tempfile.TemporaryDirectory(prefix="bench-runtime-") as tmp:
        argv = [sys.executable, "-m", "hil", "run", "--out", tmp]
        if duration_s is not None:
            argv += ["--duration", str(duration_s)]
        start = time.perf_counter()
        done = subprocess.run(argv, capture_output=True, text=True, timeout=900, check=False)
        wall = time.perf_counter() - start
        if done.returncode != 0:
            raise RuntimeError(f"hil run failed (exit {done.returncode}): {done.stderr[-2000:]}")
        run_dir = next(Path(tmp).iterdir())
        if len(list((run_dir / "plots").glob("*.png"))) < 8:
            raise RuntimeError(f"hil run left no plots in {run_dir}")
        summary = json.loads((run_dir / "summary.json").read_text())
    if summary["mode"] != "lockstep" or summary["exit"] != "completed":
        raise RuntimeError(f"the lockstep run did not complete: {summary['mode']}, {summary['exit']}")
    return wall, summary


def _world_alone(sim_s: float) -> float:
    """Simulated s per wall s of the default scenario's world alone — plant, drives, phone and the board at
    idle — advanced every plant step as the runtime does, no host."""
    from firmware_sim.cli import build_parser, make_board
    from firmware_sim.world import World
    from hil.timing.clock import LockstepClock

    scenario = load_scenario(SCENARIO)
    clock = LockstepClock()
    world = World(scenario, make_board(build_parser().parse_args(["--units", "4"]), clock))
    steps = int(sim_s / scenario.loop.plant_step_s)
    start = time.perf_counter()
    for _ in range(steps):
        clock.advance(scenario.loop.plant_step_s)
        world.advance_to(clock.now())
    return steps * scenario.loop.plant_step_s / (time.perf_counter() - start)


def _imports() -> tuple[float, float]:
    """Wall s of a process importing what ``hil run`` needs before its first tick, and of ``python -c
    pass`` (best of three each)."""
    needed = (
        "import hil.cli, hil.cli.run, hil.runtime, hil.scenario, "
        "firmware_sim.servers.transports, firmware_sim.world"
    )

    def best(code: str) -> float:
        times = []
        for _ in range(3):
            start = time.perf_counter()
            subprocess.run([sys.executable, "-c", code], check=True)
            times.append(time.perf_counter() - start)
        return min(times)

    return best(needed), best("pass")


def _hil_run_results(quick: bool) -> list[Result]:
    wall, s = _hil_run(2.0 if quick else None)
    world = _world_alone(2.0 if quick else 10.0)
    imports, bare = _imports()
    loop_factor = float(s["loop_realtime_factor"])
    note = (
        f"{s['sim_s']:.1f} s simulated: run loop {s['loop_wall_s']:.2f} s, whole command {wall:.2f} s; "
        f"targets (after the compiled kernels): >= 25x real time, <= 5 s"
    )
    return [
        Result(NAME, "hil run default: run loop", loop_factor, "sim s/wall s", "world alone (no host)", world,
               True, note),
        Result(NAME, "hil run default: whole command (imports, run, plots)", wall, "s",
               "its run loop alone", float(s["loop_wall_s"]), False),
        Result(NAME, "hil run: imports before the first tick", imports, "s", "python -c pass", bare, False),
    ]  # fmt: skip


def run(quick: bool) -> list[Result]:
    duration_s = 3.0 if quick else 10.0  # real-time runs, from the slew's start
    peer_s = 2.0 if quick else 10.0  # each peer loop, per rate
    load = os.getloadavg()[0]
    results: list[Result] = []
    cost = _world_cost()
    world_note = "" if cost < WORLD_BUDGET else (
        f"firmware-sim --world needs {cost:.2f} CPU s per simulated s here (> {WORLD_BUDGET}): it cannot "
        "keep real time; "
    )  # fmt: skip
    for rate in RATES:
        results += _jitter_results(rate, duration_s, peer_s, world_note)
    results += _busy_results(duration_s, world_note)
    results += _cli_port_results(3.0, peer_s)
    results += _latency_results(30 if quick else 300)
    results += _hil_run_results(quick)
    first = results[0]
    results[0] = replace(
        first,
        note=f"{first.note}; world {cost:.2f} CPU s per simulated s; load average {load:.2f} on "
        f"{os.cpu_count()} CPUs",
    )
    return results
