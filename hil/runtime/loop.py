"""One closed-loop run, end to end: board link, phone stream, estimator and control tasks on one
:class:`hil.timing.scheduler.Scheduler`, the run directory.

Four ways to run, one host (:class:`hil.runtime.host.Host`):

- **lockstep** (the built-in emulator, ``hil run``'s default): the board (``emu://``) and the world
  (:class:`firmware_sim.world.World`) live in this process on a :class:`LockstepClock`; a world task
  advances the world every ``plant_step_s``, and the estimator and control tasks bring it to their own
  present before they look, so whatever the order of tasks due together, the host sees the world of
  its instant. The phone's samples are handed over in-process. As fast as the CPU allows, and
  deterministic.
- **real time, built-in emulator** (``--realtime``): the same board on the wall clock; the world runs in its
  own thread and streams the phone over UDP on loopback, the way the SensaGram app streams
  (:mod:`hil.link.sources`) — the live-phone path exercised for real.
- **real time, a port** (``--port URL``: ``firmware-sim --world`` on a pty, a real board, CAN, ...): the host
  listens for the phone stream on ``--phone URL`` (``udp://HOST:PORT`` for SensaGram or
  ``firmware-sim --world``, ``http://HOST:PORT/`` for Sensor Logger's HTTP Push).
  There is no truth: the estimate stands in for it in the pointing error.
- **a recording drives a board** (``hil replay LOG --port URL``): the phone is a recorded log played on the
  run's clock (:class:`hil.link.sources.recorded.RecordedSource`), the controller holds the attitude estimated
  at the end of the warm-up against the recorded motion, and the board (a port in real time, or ``emu://``
  in lockstep) carries out the commands; the log's ground truth, if it has one, is the truth.

The phone is one :class:`hil.link.sources.PhoneSource` whatever the way: ``sim://`` (the built-in emulator's
world, in-process in lockstep, over UDP on loopback in real time), ``--phone URL`` with a port, or
``recording://`` for a replay, built by :func:`hil.link.sources.create_source` and driven the same way.

Tasks: ``estimator`` at the fastest sensor's rate (drains the samples that arrived; the merger holds the
last sample of the slower sensors), ``control`` at the control rate (board events, control, setpoint,
telemetry row), and in lockstep ``world`` at the plant step. The scheduler's absolute deadlines and its
lateness statistics (p50/p99/max per task) go into the summary.

One process serves many runs (a Monte Carlo worker runs one after another): a run keeps nothing between
runs — its clock, board, world, host and logs are its own. With ``RunOptions.out_root=None`` a run writes
no run directory at all: no telemetry rows are formatted, its events stay in memory, and its figures come
back in :class:`RunResult` (``summary`` and the per-tick ``trace`` from the slew's start).

A run may be watched and commanded while it happens (``RunOptions.observer``, :mod:`hil.runtime.observer`:
the ground station, :mod:`hil.gcs`), and a lockstep run may be paced to the wall clock (``RunOptions.pace``)
so that a person can follow it.
"""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import math
import signal
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hil.estimation.interface import Site
from hil.estimation.registry import EstimatorChoice
from hil.estimation.sensors import SensorLog
from hil.files.output import write_file
from hil.files.writing import WriterLock
from hil.link.board.session import Phase
from hil.link.sources import DEFAULT_PHONE_URL, PhoneSource, SourceContext, create_source
from hil.link.sources.checked import merge_report
from hil.link.sources.recorded import RECORDING_URL
from hil.link.sources.simulated import SIMULATED_URL
from hil.link.transports import InProcessBoard, create_transport
from hil.plugins import PluginError
from hil.runtime.codes import CODES_FILE, code_table
from hil.runtime.faults import RECOVER_WITHIN_S, BoardLink
from hil.runtime.held_signals import HeldSignals, first_signal
from hil.runtime.host import Host, TruthSample
from hil.runtime.observer import RunAborted, RunObserver, RunStart
from hil.runtime.runlog import CsvLog, EventLog, RowTap, new_run_dir, write_summary
from hil.runtime.summary import DISARM_UNCONFIRMED, RAN_OUT_UNARMED
from hil.runtime.telemetry import RunTrace, telemetry_columns
from hil.scenario import Scenario
from hil.scenario.reader import check_run_length
from hil.timing.clock import Clock, LockstepClock, WallClock
from hil.timing.priority import Scheduling, realtime
from hil.timing.scheduler import PeriodicTask, Scheduler
from hil.version import describe
from protocol.errors import CommandFailed, ConfigError, HilError, LinkError
from protocol.messages import BoardState

if TYPE_CHECKING:
    from hil.link.board import BoardClient

logger = logging.getLogger(__name__)

Progress = Callable[[Host, float], None]
"""Called after every control tick with the host and the time since the run started (s)."""

SPINUP_ALLOWANCE_S = 25.0  # beyond warm-up + duration: connect, arm, spin-up (bounded by phases.MAX_SPINUP_S)
MIN_PACE = 1e-3
"""The slowest ``--pace``: a thousandth of real time (the default run then takes ten hours). A slower one
(``1e-300``) asked the pacer to sleep past the platform's time_t: an OverflowError ended the run."""
PACE_PERIOD_S = 0.01  # a paced lockstep run waits for the wall clock every this much simulated time
DISARM_WAIT_S = 1.0  # an interrupted run waits at most this long (its clock) for the board's Disarm answer


@dataclass(frozen=True)
class ReplayInput:
    """A recorded phone log as the run's phone (``hil replay LOG --port URL``): the log, the estimator
    chosen and the site it was configured for (:func:`hil.logs.replay.configure`: inertial directions
    and gyro bias from the log); ``setup`` says what was configured."""

    log: SensorLog
    estimator: EstimatorChoice
    site: Site
    setup: tuple[str, ...] = ()


@dataclass
class RunOptions:
    """``port``: a transport URL, None for the built-in emulator and its world; ``lockstep``: None picks
    lockstep for the built-in emulator (and for a replay against ``emu://``), real time otherwise (a real
    port cannot run in lockstep); ``duration_s`` overrides the scenario's (from the slew's start);
    ``phone``: the phone source with a port (:func:`hil.link.sources.create_source`: where the host listens
    for ``udp://HOST:PORT`` or ``http://HOST:PORT/``, or any registered scheme); ``phone_wait_s``: how
    long to wait for the first phone samples on a port before giving up; ``replay``: take the phone from a
    recorded log instead (needs a port), the controller holding the attitude estimated at the end of the
    warm-up; ``out_root`` None:
    no run directory (see the module docstring); ``observer``: sees every row and event and may command
    the run (:mod:`hil.runtime.observer`); ``pace``: a lockstep run goes at most this many times as fast as
    the wall clock (1.0: real time), None: as fast as it can; ``recover_within_s``: an outage of the board
    (or a phone gap) longer than this ends the run as lost (:mod:`hil.runtime.faults`);
    ``rows_to_observer``: without a run directory, still build each tick's telemetry row and hand it to
    the observer (its ``row_columns`` attribute, if any, names the columns it wants) — a fault campaign's
    run checks its invariants on them; ``rt_priority``: a real-time run's threads under ``SCHED_FIFO`` at
    this priority (:mod:`hil.timing.priority`), None: the OS's normal scheduling;
    ``report_late_signal``: a signal that comes while a run that ended on its own writes its ending is
    held until the ending is written (:mod:`hil.runtime.held_signals`), then raised to its handler (the
    default: a campaign stops as it would have), or with this, reported in
    :attr:`RunResult.late_signal` instead (``hil run``: no plots, status 1)."""

    port: str | None = None
    lockstep: bool | None = None
    duration_s: float | None = None
    out_root: Path | None = Path("runs")
    phone: str = DEFAULT_PHONE_URL
    phone_wait_s: float = 10.0
    progress: Progress | None = None
    label: str | None = None
    replay: ReplayInput | None = None
    observer: RunObserver | None = None
    pace: float | None = None
    recover_within_s: float = RECOVER_WITHIN_S
    rows_to_observer: bool = False
    rt_priority: int | None = None
    report_late_signal: bool = False


@dataclass
class RunResult:
    """``run_dir`` (None without one), the ``summary`` (as in summary.json), the per-tick ``trace`` from
    the slew's start, and the ``events`` (kept in memory only without a run directory). ``late_signal``:
    the name of a signal (``"SIGINT"``) that came while a run that had ended on its own (completed, lost,
    aborted) wrote its ending — held back so the ending was written whole
    (:mod:`hil.runtime.held_signals`) and, with ``RunOptions.report_late_signal``, reported here for the
    caller to act on (``hil run`` draws no plots and exits 1); the summary says how the run ended."""

    run_dir: Path | None
    summary: dict[str, Any] = field(default_factory=dict)
    trace: RunTrace = field(default_factory=RunTrace)
    events: list[dict[str, Any]] = field(default_factory=list)
    late_signal: str | None = None


@dataclass(frozen=True)
class _Plan:
    """Where the phone comes from (``world``: the built-in emulator's; ``phone``: a live stream on a port;
    ``log``: a recording), on which clock, and the phone source's URL (:mod:`hil.link.sources`)."""

    source: str
    lockstep: bool
    phone: str

    @property
    def mode(self) -> str:
        return "lockstep" if self.lockstep else ("realtime" if self.source == "world" else "port")


def _plan(opts: RunOptions) -> _Plan:
    if opts.replay is not None:
        if opts.port is None:
            raise ConfigError(
                "a replay drives a board: give its port (emu://... for the in-process one)", "run"
            )
        in_process = opts.port.startswith("emu://")
        lockstep = in_process if opts.lockstep is None else opts.lockstep
        if lockstep and not in_process:
            raise ConfigError("a replay runs in lockstep only against the in-process board (emu://)", "run")
        return _Plan("log", lockstep, RECORDING_URL)
    if opts.port is None:
        return _Plan("world", True if opts.lockstep is None else opts.lockstep, SIMULATED_URL)
    if opts.lockstep:
        raise ConfigError("lockstep needs the built-in emulator (leave out --port, or use --realtime)", "run")
    return _Plan("phone", False, opts.phone)


def run(scenario: Scenario, options: RunOptions | None = None) -> RunResult:
    """Play ``scenario`` once and write its run directory; see the module docstring. Errors (a port that
    cannot be opened, a board that does not answer, no phone stream) are raised after the summary with
    the exit reason is written; a Ctrl-C ends the run early with a complete summary."""
    opts = options or RunOptions()
    plan = check_options(scenario, opts)
    if plan.source == "world":  # a fresh install compiles the world's and the host's kernels in parallel
        from hil.runtime.warmup import warm

        compiled_s = warm(scenario)
        if compiled_s is not None:
            logger.info("compiled the kernels in %.1f s (once after an install or an edit)", compiled_s)
    from hil.runtime.warmup import load_kernels

    load_kernels(scenario, world=plan.source == "world")
    with realtime(opts.rt_priority) as scheduling:  # before any thread of the run starts: they inherit it
        return _play(scenario, opts, plan, scheduling)


def check_options(scenario: Scenario, opts: RunOptions) -> _Plan:
    """What :func:`run` would refuse in ``opts`` for ``scenario`` (a ConfigError naming the option), before
    anything is set up or said; the run's plan when nothing is."""
    plan = _plan(opts)
    if opts.pace is not None and not plan.lockstep:
        raise ConfigError(f"is for lockstep runs (a {plan.mode} run keeps the wall clock)", "run --pace")
    if opts.pace is not None and not (math.isfinite(opts.pace) and opts.pace >= MIN_PACE):
        raise ConfigError(
            f"must be a factor of the wall clock of at least {MIN_PACE} (a thousandth of real time), "
            f"got {opts.pace!r}",
            "run --pace",
        )
    if opts.rt_priority is not None and plan.lockstep:
        raise ConfigError(
            "is for real-time runs (a lockstep run never waits for the wall clock)", "run --rt-priority"
        )
    if not (math.isfinite(opts.recover_within_s) and opts.recover_within_s > 0):
        raise ConfigError(
            f"must be a positive number of seconds, got {opts.recover_within_s!r}", "run --recover-within"
        )
    if opts.duration_s is not None:  # the scenario's own is checked where it is read
        if not opts.duration_s > 0:
            raise ConfigError(
                f"must be a positive number of seconds, got {opts.duration_s!r}", "run --duration"
            )
        loop = scenario.loop
        check_run_length(loop.warmup_s, opts.duration_s, loop.plant_step_s, "run --duration")
    return plan


def _play(scenario: Scenario, opts: RunOptions, plan: _Plan, scheduling: Scheduling) -> RunResult:
    """The run itself, once its options are checked and its kernels loaded, under ``scheduling``."""
    observer = opts.observer
    tap_row = None if observer is None else observer.row
    tap_event = None if observer is None else observer.event
    summary: dict[str, Any] = {"mode": plan.mode, "source": plan.source, "port": opts.port}
    summary["hil"] = describe()  # the code that made the run: its version and git revision (runs git)
    summary["scheduling"] = scheduling.describe()  # the OS's: a lateness figure means little without it
    if opts.replay is not None:
        summary["replay"] = {
            "log": opts.replay.log.source,
            "format": opts.replay.log.format,
            "setup": list(opts.replay.setup),
        }
    started = time.monotonic()
    run_dir: Path | None = None
    telemetry: CsvLog | RowTap | None = None
    if opts.rows_to_observer and tap_row is not None and opts.out_root is None:
        keep = getattr(observer, "row_columns", None)
        telemetry = RowTap(telemetry_columns(scenario.n_units), tap_row, keep)
    # in memory until the run directory's events.jsonl is open: the run directory and its files are made
    # inside the try below, so an interrupt or a full disk once it exists still ends with a summary.json
    # (it was made before git's revision was asked for: an interrupt in those ~20 ms left it empty)
    events = EventLog(None, tap=tap_event)
    built: _Built | None = None
    error: BaseException | None = None
    writing: WriterLock | None = None  # the run directory's, held until its summary.json is written
    final = FinalDisarm()
    with HeldSignals() as held:
        try:
            if opts.out_root is not None:
                run_dir = new_run_dir(opts.out_root, opts.label or scenario.name)
                writing = WriterLock(run_dir)  # a reader (hil gcs) tells a writer killed from one stalled
                write_file(run_dir / "scenario.toml", scenario.source)
                write_file(run_dir / CODES_FILE, json.dumps(code_table(), indent=1) + "\n")
                events = EventLog(run_dir / "events.jsonl", tap=tap_event)
                telemetry = CsvLog(
                    run_dir / "telemetry.csv", telemetry_columns(scenario.n_units), tap=tap_row
                )
            with contextlib.ExitStack() as stack:
                built = _build(scenario, opts, plan, telemetry, events, stack, held, final)
                if observer is not None:
                    observer.started(RunStart(built.host, built.scheduler, run_dir, plan.mode))
                loop_started = time.monotonic()
                if not plan.lockstep:
                    gc.freeze()  # a full collection would scan every object of the set-up (~120 000: ~30 ms)
                try:
                    _run_scheduler(built)
                finally:
                    built.host.end(built.scheduler.clock.now())
                    summary["loop_wall_s"] = time.monotonic() - loop_started
                    if not plan.lockstep:
                        gc.unfreeze()
                summary["exit"] = _outcome(built.host)
                held.holding = True  # the run has ended: an interrupt now is noted, the ending written
        except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM through hil's CLI (hil.cli._signals)
            held.holding = True  # first: a plain store, nothing can interrupt before it
            summary["exit"] = _interrupted(exc)
        except RunAborted as exc:
            held.holding = True
            summary["exit"] = f"aborted: {exc}"
        except BaseException as exc:
            held.holding = True
            summary["exit"] = f"error: {exc}"
            error = exc
        finally:
            held.holding = True
            final.said(summary)
            try:
                error = _finish(summary, started, built, observer, telemetry, events, run_dir, error)
            finally:
                if writing is not None:
                    writing.release()
    if error is not None:
        raise error
    trace = built.host.trace if built is not None else RunTrace()
    late = None
    if held.received and not summary["exit"].startswith("interrupted"):
        late = held.received[0]  # a run that ended on its own, interrupted while it wrote its ending
        if not opts.report_late_signal:
            signal.raise_signal(signal.Signals[late])  # its handler's again: raised as it would have been
    return RunResult(run_dir, summary, trace, list(events.events), late)


def _finish(
    summary: dict[str, Any],
    started: float,
    built: _Built | None,
    observer: RunObserver | None,
    telemetry: CsvLog | RowTap | None,
    events: EventLog,
    run_dir: Path | None,
    error: BaseException | None,
) -> BaseException | None:
    """The run's ending, whatever ended it: its figures into ``summary``, its logs closed, ``summary.json``
    written (with what the logs could not write, after a refused write), the observer told. Returns the
    error the run is to raise: ``error``, or the first refused write of a run that had none."""
    summary["wall_s"] = time.monotonic() - started
    if built is not None:
        host = built.host
        if host.ended_at is None:  # ended before its loop ran (the arming failed): now
            host.end(built.scheduler.clock.now())
        assert host.ended_at is not None
        ending = getattr(observer, "ending", None)  # optional (RunObserver): before the summary
        if ending is not None:
            ending(host.ended_at)
        summary.update(built.host.summary())
        exit_reason = str(summary.get("exit"))
        ran_its_time = exit_reason == "completed" or exit_reason.startswith(
            (DISARM_UNCONFIRMED, RAN_OUT_UNARMED)
        )
        if summary.get("lost") and ran_its_time:
            # heard only on the way out (its final Disarm failing with it): the board lost, said first
            summary["exit"] = f"lost: {summary['lost']}"
        summary["link"] = {}  # its place in summary.json: filled last, with the source's report
        scheduler = built.scheduler
        summary["tasks"] = scheduler.summary()
        summary["sim_s"] = scheduler.clock.now() - scheduler.origin
        if summary["wall_s"] > 0:
            summary["realtime_factor"] = summary["sim_s"] / summary["wall_s"]
        if summary.get("loop_wall_s", 0.0) > 0:
            summary["loop_realtime_factor"] = summary["sim_s"] / summary["loop_wall_s"]
        source = built.source
        later = ("telemetry_rows_not_written", "events_not_written", "events_not_written_dropped")
        # last: a user's report may only add sections the run has not written (nor writes after: later)
        for merge in (
            lambda: summary.update(link=_link_stats(host)),  # a user's transport's counters() in it
            lambda: merge_report(summary, source, later),
        ):
            try:
                merge()
            except HilError as exc:  # a user's plugin that failed them: the run's error, if it had none
                if error is None:
                    summary["exit"] = f"error: {exc}"
                    error = exc
    try:
        if telemetry is not None:
            telemetry.close()
    except OSError as exc:  # the writer thread's error (a full disk): the run's error if it had none
        if error is None:
            summary["exit"] = f"error: {exc}"
            error = exc
    events.close()
    if events.failed is not None and error is None:
        summary["exit"] = f"error: {events.failed}"
        error = events.failed
    _unwritten(summary, telemetry, events)
    if run_dir is not None:
        try:
            write_summary(run_dir, summary)
        except OSError as exc:  # the disk is full or the directory gone: the run's error, said as such
            if error is None or error is events.failed:
                error = exc
            else:  # the run's own error is raised; this one is said here
                logger.error("%s", exc)
    if observer is not None:
        observer.finished(summary)
    return error


def _unwritten(summary: dict[str, Any], telemetry: CsvLog | RowTap | None, events: EventLog) -> None:
    """What the run's logs could not write (a full disk), in its summary: the telemetry rows counted, the
    events themselves (the newest the log kept, older ones counted)."""
    rows = getattr(telemetry, "rows_not_written", 0)
    if rows:
        summary["telemetry_rows_not_written"] = rows
    if events.unwritten:
        summary["events_not_written"] = list(events.unwritten)
        if events.dropped:
            summary["events_not_written_dropped"] = events.dropped


@dataclass
class _Built:
    host: Host
    scheduler: Scheduler
    until: float  # clock time (s) at which the run ends whatever happened
    source: PhoneSource


class _HeldEvents:
    """``events.jsonl``'s writer while the run is set up: the board's handshake events are older than the
    records of the set-up, and the host's watch writes them once the host exists, so the set-up's records
    wait until :meth:`release`, then go straight through (``events.jsonl`` stays in time order)."""

    def __init__(self, events: EventLog) -> None:
        self._events = events
        self._held: list[tuple[float, str, dict[str, Any]]] | None = []

    def __call__(self, t: float, kind: str, **fields: Any) -> None:
        if self._held is None:
            self._events.write(t, kind, **fields)
        else:
            self._held.append((t, kind, fields))

    def release(self) -> None:
        """Write what was held, in order; what comes after is written at once."""
        held, self._held = self._held or [], None
        for t, kind, fields in held:
            self._events.write(t, kind, **fields)


def _build(
    scenario: Scenario,
    opts: RunOptions,
    plan: _Plan,
    telemetry: CsvLog | RowTap | None,
    events: EventLog,
    stack: contextlib.ExitStack,
    held: HeldSignals,
    final: FinalDisarm,
) -> _Built:
    """Board client, phone source (:func:`hil.link.sources.create_source` on ``plan.phone``), host and
    scheduler for ``plan``; everything opened is closed by ``stack``."""
    from hil.link.board import BoardClient, connect_within

    clock: Clock = LockstepClock() if plan.lockstep else WallClock()
    if plan.source == "world":
        link = _in_process_board(scenario.emulator_url())
        client = BoardClient(link, clock=clock)
    else:
        assert opts.port is not None
        client = BoardClient(opts.port, clock=clock)
    stack.push(_closing(client.close, "the board link", events, clock))
    events.write(clock.now(), "connecting", port=opts.port or scenario.emulator_url())
    # the first handshake: a port that vanishes or cannot be opened meanwhile (a board unplugged and
    # plugged back, a firmware-sim restarting or killed before it answered) is tried again for up to the
    # run's outage bound, each try an events.jsonl record; no board, another protocol or a port another
    # host holds fails at once
    info = connect_within(
        client,
        opts.recover_within_s,
        lambda retry: events.write(retry.t, "connect_retry", attempt=retry.attempt, detail=str(retry.error)),
    )
    # unwound before the close: the link still up
    stack.push(_disarm_on_the_way_out(client, events, held, final))
    handshake = client.drain_events()
    write_event = _HeldEvents(events)
    write_event(clock.now(), "connected", board=info.describe(), units=info.n_units)
    if info.n_units != scenario.n_units:
        raise ConfigError(
            f"the board has {info.n_units} units, the scenario's spacecraft {scenario.n_units}", "run --port"
        )
    replay = opts.replay
    duration = opts.duration_s
    if replay is not None:  # the recording's own still window gave the gyro bias: no calibration here
        scenario = scenario.with_changes(loop=replace(scenario.loop, calibrate_rate_bias=False))
        duration = replay.log.end - replay.log.start  # the recording sets the end, not the host
    context = SourceContext(
        scenario, clock, plan.lockstep, client.transport, write_event, None if replay is None else replay.log
    )
    source = create_source(plan.phone, context)
    stack.push(_closing(source.close, "the phone source", events, clock))

    def truth() -> TruthSample | None:
        found = source.truth(clock.now())
        return None if found is None else TruthSample(found.R, found.omega)

    host = Host(
        scenario,
        client,
        telemetry,
        events,
        truth,
        duration,
        make_estimator=None if replay is None else partial(replay.estimator.build, replay.site),
        hold=replay is not None,
        recover_within_s=opts.recover_within_s,
    )
    host.watch.on_events(handshake)
    final.arm_outstanding = lambda: host.watch.arm_outstanding
    final.heard = host.heard_on_the_way_out
    write_event.release()
    # before arming: the board's link watchdog is fed while we wait, not by the armed loop
    source.wait_ready(opts.phone_wait_s, lambda: host.watch.on_events(client.service()))
    try:
        client.arm()
    except (CommandFailed, LinkError) as exc:  # a stall, a reset, a vanished port while arming: a fault
        host.watch.on_events(client.drain_events())
        events.write(clock.now(), "arm_failed", detail=str(exc))
        host.watch.request_arm()  # re-armed through the protocol on the control tick, as after any fault
    else:
        host.watch.on_events(client.drain_events())  # what the board said while arming goes before "armed"
        events.write(clock.now(), "armed")
    origin = clock.now()
    until = _time_limit(scenario, opts, origin) + opts.recover_within_s
    source_end = source.start(origin)
    if source_end is not None:  # a recording: the tick after its last sample ends the run
        until = source_end
    estimator_hz = source.rate_hz or estimator_rate_hz(scenario)

    scheduler_ref: list[Scheduler] = []

    def estimator_task(_due: float) -> None:
        host.feed(source.drain(clock.now()), clock.now())
        host.senders.read(clock.now(), source.senders())  # other phones on its port (a live receiver)

    observer = opts.observer

    def control_task(due: float) -> None:
        if observer is not None:
            observer.tick(clock.now())  # commands from outside act here, in the control thread
        source.advance(clock.now())  # a simulated world to the present before the board is serviced
        events = client.service()
        # now after the service: the telemetry it took is not from the future; the deadline tells a stall
        host.tick(clock.now(), events, due)
        if opts.progress is not None:
            opts.progress(host, clock.now() - origin)
        if source.exhausted:
            host.finished = True  # the whole recording was played
        if host.finished:
            scheduler_ref[0].stop()

    tasks = [
        *source.tasks(),
        PeriodicTask("estimator", 1.0 / estimator_hz, estimator_task),
        PeriodicTask("control", 1.0 / scenario.loop.control_rate_hz, control_task),
    ]
    if opts.pace is not None:
        tasks.append(_pacer(opts.pace, origin))
    scheduler = Scheduler(clock, tasks, origin=origin)
    scheduler_ref.append(scheduler)
    return _Built(host, scheduler, until, source)


def _run_scheduler(built: _Built) -> None:
    """Run the scheduler to the run's time limit, moved on by the time the operator kept the run
    suspended (a Disarm then an Arm: :attr:`Host.time_limit_extension_s`); a suspension still on at the
    limit does not move it, so a Disarm without an Arm ends the run there."""
    until = built.until
    while True:
        built.scheduler.run(until=until)
        host = built.host
        extended = built.until + host.time_limit_extension_s
        if host.finished or extended <= until + 1e-9:
            return
        until = extended


def _outcome(host: Host) -> str:
    """The run's exit reason when its loop ended on its own: ``lost: ...`` if an outage of the board (or a
    phone gap) outlasted its bound or was still on at the end; ``disarmed by the operator ...`` if the
    operator's Disarm suspended the run and no Arm followed; ``incomplete: ...`` if a replay's recording ran
    out before the slew started (its warm-up never done: a phone gap or a board reset near the log's end
    restarted it — it once said ``completed``); ``completed`` once the run's time after the slew's start
    (its suspensions not counted) is up; else the time limit."""
    assert host.ended_at is not None
    lost = host.lost or host.journal.open_at_end(host.ended_at)
    if lost is not None:
        return f"lost: {lost}"
    if host.suspended_since is not None:
        said = f"disarmed by the operator at t={host.suspended_since:.3f} s and not armed again"
        refused = [
            e
            for e in host.operator_log
            if e["command"] == "arm" and e["status"] == "refused" and e["t"] >= host.suspended_since
        ]
        if refused:  # the operator did Arm: the command never reached the board (no session then)
            last = refused[-1]
            said += f" (an Arm at t={last['t']:.3f} s was refused: {last.get('reason', 'refused')})"
        return said
    if host.finished and host.phases.slew_start is None:  # a recording that ran out during the warm-up
        return "incomplete: the recording ended before the slew started (the controller never held it)"
    if host.finished and (unarmed := _not_in_hand(host)) is not None:
        return f"{RAN_OUT_UNARMED} {unarmed}"
    if host.finished:
        return "completed"
    slew_start = host.phases.slew_start
    if slew_start is None:
        return "time limit (the slew never started)"
    # it was said "(the slew never started)" of a run that had slewed and held (a recording's end, a
    # source's end time, before the run's time after its slew was up)
    return f"time limit (the slew started at t={slew_start:.3f} s; the run's time after it not reached)"


def _not_in_hand(host: Host) -> str | None:
    """Why the board was not in hand and ARMED at the run's last control tick, or None if it was: the
    operator's Arm given a few ms before the end not yet carried out (the run said ``completed`` with the
    board DISARMED in its last row), a re-arm after a failsafe under way, the board's telemetry stale."""
    view = host.last_view
    if view is None:
        return None
    tel = view.telemetry
    if view.link is BoardLink.LIVE and tel is not None and tel.state is BoardState.ARMED:
        return None
    if tel is None:
        return f"{view.link.name.lower()} (no live telemetry at the end)"
    arms = [e for e in host.operator_log if e["command"] == "arm" and e["status"] != "refused"]
    after = f" (the operator's Arm at t={arms[-1]['t']:.3f} s not yet carried out)" if arms else ""
    return f"{tel.state.name}, not armed{after}"


def _interrupted(exc: BaseException) -> str:
    """The exit reason of an interrupted run, naming the signal that interrupted it first
    (:func:`~hil.runtime.held_signals.first_signal`): ``interrupted (SIGTERM)``."""
    return f"interrupted ({first_signal(exc).name})"


@dataclass
class FinalDisarm:
    """The Disarm the run's way out sends (:func:`_disarm_on_the_way_out`) and how it went: ``outcome``
    (``summary.json``'s ``final_disarm``: ``sent``; ``ok`` — the board confirmed disarmed, True also for a
    board known DISARMED that needed none, None without a session to ask; ``reason``, the ``error`` of one
    that failed, the board's ``state`` as last known) once the way out ran. ``arm_outstanding`` says
    whether an Arm of the host's may still reach the board (the host's watch, once it exists)."""

    arm_outstanding: Callable[[], bool] = lambda: False
    outcome: dict[str, Any] | None = None
    # what the board client's events on the way out go to (the host's record, once it exists)
    heard: Callable[[list[Any]], None] = lambda events: None

    def said(self, summary: dict[str, Any]) -> None:
        """``final_disarm`` into ``summary``. A run that completed but whose board is not confirmed
        disarmed (the final Disarm failed: a board frozen over the run's end, a link gone) does not say
        ``completed`` (status 0, only ``events.jsonl`` said ``disarm_failed``): ``incomplete: the run
        completed, but the board is not confirmed disarmed (…)``, status 1 — the board's state said in the
        exit, as an abort whose board still says ARMED says it. Any other exit already says the run did
        not complete; ``final_disarm`` and the printed summary say the Disarm's failure beside it."""
        outcome = self.outcome
        if outcome is None:
            return
        summary["final_disarm"] = outcome
        if outcome["ok"] is False and summary.get("exit") == "completed":
            summary["exit"] = f"{DISARM_UNCONFIRMED} (the final Disarm failed: {outcome['error']})"


def _closing(close: Callable[[], object], what: str, events: EventLog, clock: Clock) -> Callable[..., bool]:
    """An exit callback for the run's ExitStack that calls ``close``. A close that fails when the run
    ended well is the run's error; one that fails while the run is ending on an error or an interrupt is
    said (``close_failed`` in events.jsonl, naming ``what``, and logged) and does not replace it — a
    user's phone source whose ``close`` raised after its ``drain`` had failed made the run's exit name the
    close, the drain's fault lost."""

    def on_exit(exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> bool:
        if exc is None:
            close()
            return False
        try:
            close()
        except Exception as failure:
            error = f"{type(failure).__name__}: {failure}"
            logger.warning("closing %s failed as the run ended on %r: %s", what, exc, error)
            events.write(clock.now(), "close_failed", what=what, error=error)
        return False

    return on_exit


def _disarm_on_the_way_out(
    client: BoardClient, events: EventLog, held: HeldSignals, final: FinalDisarm
) -> Callable[..., bool]:
    """An exit callback for the run's ExitStack: when the run is interrupted, disarm the board the host
    holds before the link is closed, best effort within :data:`DISARM_WAIT_S`, and say so in events.jsonl
    (``disarmed``, or ``disarm_failed`` with why). Closing the port alone leaves an armed board spinning its
    rotors until its own link watchdog fails it safe (FAILSAFE after its timeout, the operator's Disarm
    never given). The signal after the interrupt is held (``held``): the Disarm is made and waited for
    however soon the user presses again; one more gives the wait up (said), not the run's summary. A run
    that ends on an error of the host's own (its run directory's disk full, a reader thread's failure)
    with the board in hand and ARMED disarms it the same way, the error as the reason (it once left the board
    spinning until its watchdog tripped); an abort has disarmed it already, unless the board still says
    ARMED (it acknowledged the abort's Disarm and did not carry it out): then it is tried again. A run
    that ends by itself (completed, or lost and back) with the board in hand and ARMED disarms it too,
    reason ``run ended``: let go armed, the board spun its rotors at the last setpoint until its link
    watchdog tripped, and the next session found it in FAILSAFE with a link-lost fault no one had
    suffered. Not only an ARMED board: one in FAILSAFE, in a state not known, or with an Arm of the
    host's still in flight (a re-arm, the operator's Arm) is sent the Disarm too — a host paused across
    the run's end read FAILSAFE, re-armed, and let go of a board that the Arm then armed, with no one
    commanding it; a Disarm is safe in every state. Only a board known DISARMED (or still booting) with no
    Arm outstanding is left as it is. Never suppresses the exception. How it went is ``final.outcome``
    (``summary.json``'s ``final_disarm``; a run that completed with a board not confirmed disarmed does
    not say ``completed``: :meth:`FinalDisarm.said`).
    After the Disarm (or none) a signal is held (``held``) however the run ended: the link is closed and
    the run's ending written whole."""

    def on_exit(exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> bool:
        try:
            _disarm(exc)
        finally:
            held.holding = True
        return False

    def _disarm(exc: BaseException | None) -> None:
        state = client.state
        if isinstance(exc, KeyboardInterrupt):
            reason = _interrupted(exc)
        elif client.connected and (state not in _LEFT_AS_IT_IS or final.arm_outstanding()):
            reason = "run ended" if exc is None else f"{_ending(exc)}: {exc}"
        else:  # known disarmed (nothing to send), or no session to send it in (a lost link: not known)
            known = None if state is None else state.name
            final.outcome = {"sent": False, "ok": True if client.connected else None, "state": known}
            return
        if not client.connected:
            error = "no session with the board"
            events.write(client.clock.now(), "disarm_failed", reason=reason, error=error)
            final.outcome = {"sent": False, "ok": False, "reason": reason, "error": error, "state": None}
            return
        final.outcome = {"sent": True, "ok": None, "reason": reason, "state": None}
        try:
            client.disarm(timeout=DISARM_WAIT_S)
        except (HilError, KeyboardInterrupt) as failure:
            error = str(failure) or f"{type(failure).__name__} while waiting"
            if client.session.phase is Phase.HANDSHAKING and not isinstance(failure, KeyboardInterrupt):
                # the board reset under the Disarm (the session shakes hands again): the handshake told
                # why, and the reset is reported — counted, not only said in the Disarm's error
                with contextlib.suppress(HilError, KeyboardInterrupt):  # given up: said as it stands
                    client.wait_for(lambda: client.session.phase is not Phase.HANDSHAKING, DISARM_WAIT_S)
            final.heard(client.drain_events())  # the reset into the record before the Disarm's outcome
            if client.state in _LEFT_AS_IT_IS and not final.arm_outstanding():
                # the board's own word since: booting or DISARMED (a board that reset drives nothing;
                # every command of the old session was abandoned) — not "not confirmed disarmed"
                events.write(client.clock.now(), "disarmed", reason=reason, detail=error)
                final.outcome.update(ok=True, detail=error)
            else:
                events.write(client.clock.now(), "disarm_failed", reason=reason, error=error)
                final.outcome.update(ok=False, error=error)
        else:
            final.heard(client.drain_events())
            events.write(client.clock.now(), "disarmed", reason=reason)
            final.outcome["ok"] = True
        state = client.state
        final.outcome["state"] = None if state is None else state.name

    return on_exit


_LEFT_AS_IT_IS = (BoardState.DISARMED, BoardState.BOOT)
"""The board states the run's way out sends no Disarm to, unless an Arm of the host's is in flight: known
disarmed, or still booting (which refuses a Disarm and drives nothing)."""


def _ending(exc: BaseException) -> str:
    """How a run that raised ``exc`` ended, as a Disarm on its way out gives the reason: an abort whose
    board still says ARMED (its Disarm acknowledged, not carried out), or an error of the host's own."""
    return "aborted" if isinstance(exc, RunAborted) else "error"


def _in_process_board(url: str) -> InProcessBoard:
    """The built-in emulator at ``url`` (``emu://``), which ``firmware_sim`` registers as a transport."""
    link = create_transport(url)
    if not isinstance(link, InProcessBoard):
        raise ConfigError(f"{url} is not an in-process board with a world", "run")
    return link


def _pacer(pace: float, origin: float) -> PeriodicTask:
    """A lockstep task that waits, every :data:`PACE_PERIOD_S` of simulated time, until the wall clock has
    caught up with the simulated time since ``origin`` divided by ``pace`` (``pace`` times faster than the
    wall clock; a run slower than that is not held)."""
    wall_origin: list[float] = []

    def pace_task(due: float) -> None:
        now = time.monotonic()
        if not wall_origin:
            wall_origin.append(now - (due - origin) / pace)
        ahead = wall_origin[0] + (due - origin) / pace - now
        if ahead > 0.0:
            time.sleep(ahead)

    return PeriodicTask("pace", PACE_PERIOD_S, pace_task)


def _time_limit(scenario: Scenario, opts: RunOptions, origin: float) -> float:
    duration = scenario.slew.duration_s if opts.duration_s is None else opts.duration_s
    return origin + scenario.loop.warmup_s + duration + SPINUP_ALLOWANCE_S


def _link_stats(host: Host) -> dict[str, Any]:
    try:
        stats = host.client.stats()
    except PluginError:  # a user's transport's counters(): the run's error (_finish)
        raise
    except HilError:
        return {}
    return asdict(stats)


def estimator_rate_hz(scenario: Scenario) -> float:
    """The fastest sensor's rate (Hz): the estimator task's."""
    return max(s.rate_hz for s in (scenario.phone.gyr, scenario.phone.acc, scenario.phone.mag))
