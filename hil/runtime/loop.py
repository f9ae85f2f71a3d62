"""One closed-loop run, end to end: board link, phone stream, estimator and control tasks on one
:class:`hil.scheduler.Scheduler`, the run directory.

Three ways to run, one host (:class:`hil.runtime.host.Host`):

- **lockstep** (the built-in emulator, ``hil run``'s default): the board (``emu://``) and the world
  (:class:`firmware_sim.world.World`) live in this process on a :class:`LockstepClock`; a world task steps
  the plant every ``plant_step_s`` and hands the phone's samples over in-process. As fast as the CPU allows,
  and deterministic.
- **real time, built-in emulator** (``--realtime``): the same board on the wall clock; the world runs in its
  own thread and streams the phone over HTTP on loopback, the way the Sensor Logger app streams
  (:mod:`hil.sources.phone_push`) — the live-phone path exercised for real.
- **real time, a port** (``--port URL``: ``firmware-sim --world`` on a pty, a real board, CAN, ...): the host
  listens for the phone stream on ``--phone HOST:PORT`` (from ``firmware-sim --world`` or a real phone).
  There is no truth: the estimate stands in for it in the pointing error.

Tasks: ``estimator`` at the fastest sensor's rate (drains the samples that arrived; the merger holds the
last sample of the slower sensors), ``control`` at the control rate (board events, control, setpoint,
telemetry row), and in lockstep ``world`` at the plant step. The scheduler's absolute deadlines and its
lateness statistics (p50/p99/max per task) go into the summary.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil.clock import Clock, LockstepClock, WallClock
from hil.runlog import CsvLog, EventLog, new_run_dir, write_summary
from hil.runtime.host import Host, TruthSample, telemetry_columns
from hil.scenario import Scenario
from hil.scheduler import PeriodicTask, Scheduler
from hil.sensors import SensorSample
from protocol.errors import ConfigError, HilError, LinkTimeout

logger = logging.getLogger(__name__)

Progress = Callable[[Host, float], None]
"""Called after every control tick with the host and the time since the run started (s)."""

SPINUP_ALLOWANCE_S = 25.0  # beyond warm-up + duration: connect, arm, spin-up (bounded by Host.MAX_SPINUP_S)


@dataclass
class RunOptions:
    """``port``: a transport URL, None for the built-in emulator; ``lockstep``: None picks lockstep for the
    built-in emulator and real time for a port (a port cannot run in lockstep); ``duration_s`` overrides the
    scenario's (from the slew's start); ``phone``: HOST:PORT the host listens on for the phone stream in real
    time (port 0: any free port, for the built-in emulator); ``phone_wait_s``: how long to wait for the first
    phone samples on a port before giving up."""

    port: str | None = None
    lockstep: bool | None = None
    duration_s: float | None = None
    out_root: Path = Path("runs")
    phone: str = "127.0.0.1:8123"
    phone_wait_s: float = 10.0
    plots: bool = True
    progress: Progress | None = None
    label: str | None = None


@dataclass
class RunResult:
    run_dir: Path
    summary: dict[str, Any] = field(default_factory=dict)


def run(scenario: Scenario, options: RunOptions | None = None) -> RunResult:
    """Play ``scenario`` once and write its run directory; see the module docstring. Errors (a port that
    cannot be opened, a board that does not answer, no phone stream) are raised after the summary with
    the exit reason is written; a Ctrl-C ends the run early with a complete summary."""
    opts = options or RunOptions()
    lockstep = opts.port is None if opts.lockstep is None else opts.lockstep
    if lockstep and opts.port is not None:
        raise ConfigError("lockstep needs the built-in emulator (leave out --port, or use --realtime)", "run")
    run_dir = new_run_dir(opts.out_root, opts.label or scenario.name)
    (run_dir / "scenario.toml").write_text(scenario.source)
    telemetry = CsvLog(run_dir / "telemetry.csv", telemetry_columns(scenario.n_units))
    events = EventLog(run_dir / "events.jsonl")
    mode = "lockstep" if lockstep else ("realtime" if opts.port is None else "port")
    summary: dict[str, Any] = {"mode": mode, "port": opts.port}
    started = time.monotonic()
    host: Host | None = None
    scheduler: Scheduler | None = None
    error: BaseException | None = None
    try:
        with contextlib.ExitStack() as stack:
            host, scheduler = _build(scenario, opts, mode, telemetry, events, stack)
            scheduler.run(until=_time_limit(scenario, opts, scheduler.origin))
            summary["exit"] = "completed" if host.finished else "time limit (the slew never started)"
    except KeyboardInterrupt:
        summary["exit"] = "interrupted"
    except BaseException as exc:
        summary["exit"] = f"error: {exc}"
        error = exc
    finally:
        summary["wall_s"] = time.monotonic() - started
        if host is not None:
            summary.update(host.summary())
            summary["link"] = _link_stats(host)
        if scheduler is not None:
            summary["tasks"] = scheduler.summary()
            summary["sim_s"] = scheduler.clock.now() - scheduler.origin
            if summary["wall_s"] > 0:
                summary["realtime_factor"] = summary["sim_s"] / summary["wall_s"]
        telemetry.close()
        events.close()
        write_summary(run_dir, summary)
    if error is not None:
        raise error
    if opts.plots:
        from hil.plots.run import plot_run

        plot_run(run_dir)
    return RunResult(run_dir, summary)


def _time_limit(scenario: Scenario, opts: RunOptions, origin: float) -> float:
    duration = scenario.slew.duration_s if opts.duration_s is None else opts.duration_s
    return origin + scenario.loop.warmup_s + duration + SPINUP_ALLOWANCE_S


def _build(
    scenario: Scenario, opts: RunOptions, mode: str, telemetry: CsvLog, events: EventLog,
    stack: contextlib.ExitStack,
) -> tuple[Host, Scheduler]:  # fmt: skip
    """Board client, world or phone stream, host and scheduler for ``mode``; everything opened is closed
    by ``stack``."""
    from hil.board import BoardClient
    from hil.transports.emulator import EmulatorTransport

    clock: Clock = LockstepClock() if mode == "lockstep" else WallClock()
    truth: Callable[[], TruthSample | None] = lambda: None  # noqa: E731
    world = None
    if mode == "port":
        assert opts.port is not None
        client = BoardClient(opts.port, clock=clock)
    else:
        link = EmulatorTransport(scenario.emulator_url(), clock)
        client = BoardClient(link, clock=clock)
    stack.callback(client.close)
    events.write(clock.now(), "connecting", port=opts.port or scenario.emulator_url())
    info = client.connect()
    events.write(clock.now(), "connected", board=info.describe(), units=info.n_units)
    if info.n_units != scenario.n_units:
        raise ConfigError(
            f"the board has {info.n_units} units, the scenario's spacecraft {scenario.n_units}", "run --port"
        )
    pending: list[SensorSample] = []
    drain: Callable[[], list[SensorSample]]
    if mode != "lockstep":
        from hil.sources.phone_push import PhonePushServer

        host_name, port = _split_address(opts.phone if mode == "port" else "127.0.0.1:0")
        server = PhonePushServer(host_name, port)
        stack.callback(server.close)
        drain = server.drain
        events.write(clock.now(), "phone_listening", url=server.url)
    if mode != "port":
        from firmware_sim.world import World

        link_board = link.board
        with link.lock:
            world = World(scenario, link_board)
        lock = link.lock

        def truth() -> TruthSample:
            with lock:
                return TruthSample(world.state.R[0].copy(), world.state.omega[0].copy())

    if mode == "realtime":
        import sys

        from firmware_sim.world import WorldStreamer

        # The world thread shares this interpreter: hand the GIL over every 0.5 ms (default 5 ms), so a
        # control deadline waits at most that long for it.
        stack.callback(sys.setswitchinterval, sys.getswitchinterval())
        sys.setswitchinterval(5e-4)

        assert world is not None
        streamer = WorldStreamer(world, link.lock, server.url).start()
        stack.callback(streamer.close)
    host = Host(scenario, client, telemetry, events, truth, opts.duration_s)
    client.arm()
    events.write(clock.now(), "armed")
    if mode == "port":
        _wait_for_phone(server, opts.phone_wait_s, pending)
    if mode == "lockstep":
        assert world is not None

        def drain() -> list[SensorSample]:
            out = pending.copy()
            pending.clear()
            return out

    origin = clock.now()
    scheduler_ref: list[Scheduler] = []

    def estimator_task(_due: float) -> None:
        host.feed(drain())

    def control_task(_due: float) -> None:
        host.tick(clock.now(), client.service())
        if opts.progress is not None:
            opts.progress(host, clock.now() - origin)
        if host.finished:
            scheduler_ref[0].stop()

    tasks = [
        PeriodicTask("estimator", 1.0 / estimator_rate_hz(scenario), estimator_task),
        PeriodicTask("control", 1.0 / scenario.loop.control_rate_hz, control_task),
    ]
    if mode == "lockstep":
        assert world is not None
        w = world

        def world_task(_due: float) -> None:
            pending.extend(w.advance_to(clock.now()))

        tasks.insert(0, PeriodicTask("world", scenario.loop.plant_step_s, world_task))
    scheduler = Scheduler(clock, tasks, origin=origin)
    scheduler_ref.append(scheduler)
    return host, scheduler


def _wait_for_phone(server: Any, wait_s: float, pending: list[SensorSample]) -> None:
    """The first phone samples within ``wait_s`` (wall clock), or a clear error saying where to send them."""
    end = time.monotonic() + wait_s
    while time.monotonic() < end:
        if server.stats.samples:
            return
        time.sleep(0.05)
    raise LinkTimeout(
        f"no phone samples on {server.url} within {wait_s:.0f} s: start `firmware-sim --world SCENARIO` "
        "(it pushes its simulated phone there) or point a phone's Sensor Logger HTTP Push at it"
    )


def _split_address(address: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    try:
        return host or "127.0.0.1", int(port)
    except ValueError:
        raise ConfigError(f"{address!r} is not HOST:PORT", "--phone") from None


def _link_stats(host: Host) -> dict[str, Any]:
    try:
        stats = host.client.stats()
    except HilError:
        return {}
    from dataclasses import asdict

    return asdict(stats)


def estimator_rate_hz(scenario: Scenario) -> float:
    """The fastest sensor's rate (Hz): the estimator task's."""
    return max(s.rate_hz for s in (scenario.phone.gyr, scenario.phone.acc, scenario.phone.mag))
