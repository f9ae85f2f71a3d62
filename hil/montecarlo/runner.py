"""The worker's side of a campaign: turn a run's draws into the scenario it flies (:func:`realise`) and run
it through the one closed loop (:func:`hil.runtime.run` in lockstep: the host, the emulated board
``emu://`` with its protocol, watchdog and failsafe, and the world), several runs one after another per
task (:func:`run_chunk`).

A realised scenario carries everything a run disperses: the true spacecraft the world flies
(``Scenario.true_spacecraft``; the host's controller keeps the nominal ``spacecraft``), the phone and its
noise seed (``phone``, ``seed``), the start attitude and the slew (``slew``), and the link outages as the
board's own fault injection (``fault_options["stall"]``, firmware-sim's ``--stall AT:DURATION`` on the
board's clock), so the board's watchdog, its failsafe and the host's re-arm are what an outage tests. A
run writes no run directory (``RunOptions(out_root=None)``): its metrics and its decimated traces come from
the host's per-tick trace in memory.

Nothing here raises for a bad run: a run whose parameters the model refuses, or whose simulation raises,
comes back as a failed :class:`RunResult` with the error text; the chunk's other runs go on.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from hil import so3
from hil.runtime.invariants import INVARIANTS, Bounds, InvariantReport, check_run
from hil.runtime.observer import Observers
from hil.runtime.operator import ScheduledOperator
from hil.runtime.record import RunRecorder
from hil.scenario import Scenario
from hil.scenario.config import SlewScenario
from hil.scenario.phone import PhoneSpec
from hil.scenario.reader import phone_out_of_range
from hil.vscmg import SpacecraftParams
from hil.vscmg.params import inertia_tensor
from protocol.errors import ConfigError, HilError, RunHung

from .dispersions import SENSOR_KINDS, RunParams
from .fault_plan import board_of, check_board, fault_options, operator_schedule
from .metrics import METRICS, TRACES, decimated_trace, run_metrics, trace_length

T = TypeVar("T")


@dataclass(frozen=True)
class RunResult:
    """One finished run: ``ok`` with its ``metrics`` (:data:`~.metrics.METRICS`) and ``trace`` (see
    :func:`~.metrics.decimated_trace`), or failed with ``error`` ("ExceptionType: message"). ``columns``
    are its drawn parameters (always, so a failed run can be reproduced and looked into); ``wall_s`` its
    share of the chunk's compute time; ``checks`` (a fault campaign's run) its exit, each invariant's
    violations and the faults' detection and recovery times (:data:`CHECK_COLUMNS`)."""

    index: int
    ok: bool
    columns: Mapping[str, float | int | str]
    metrics: Mapping[str, float]
    trace: NDArray[np.float32] | None
    error: str = ""
    wall_s: float = 0.0
    checks: Mapping[str, float | int | str] = field(default_factory=dict)

    @classmethod
    def failed(
        cls,
        run: RunParams,
        error: BaseException | str,
        wall_s: float = 0.0,
        checks: Mapping[str, Any] | None = None,
    ) -> RunResult:
        text = error if isinstance(error, str) else describe(error)
        return cls(run.index, False, run.columns, {}, None, text, wall_s, checks or {})


def describe(exc: BaseException) -> str:
    """An error as one line: type and message, and for an unexpected error (not one of the project's, which
    say where themselves) the file:line it was raised at."""
    frames = traceback.extract_tb(exc.__traceback__)
    at = ""
    if frames and not isinstance(exc, HilError):
        at = f" (at {frames[-1].filename.rsplit('/', 1)[-1]}:{frames[-1].lineno})"
    return f"{type(exc).__name__}: {exc}{at}".replace("\n", " | ")


# --------------------------------------------------------------------------- a run's scenario
def realise(scenario: Scenario, run: RunParams) -> Scenario:
    """``scenario`` with run ``run``'s draws applied (see the module docstring); a value the model refuses
    is a ConfigError naming the run and the parameter."""
    v = run.values
    changes: dict[str, object] = {
        "true_spacecraft": _checked(run, "spacecraft", lambda: _spacecraft(scenario.spacecraft, run)),
        "phone": _checked(run, "sensors", lambda: _phone(scenario.phone, v)),
        "slew": _checked(run, "initial/manoeuvre", lambda: _slew(scenario.slew, run)),
        "seed": run.phone_seed,
    }
    options: dict[str, Any] = dict(scenario.fault_options)
    if run.outages:
        stalls = options.get("stall", [])
        stalls = list(stalls) if isinstance(stalls, list) else [stalls]
        stalls += [f"{start!r}:{duration!r}" for start, duration in run.outages]
        options["stall"] = stalls
    if run.faults:
        check_board(sorted({f.kind for f in run.faults}), board_of(scenario), f"run {run.index}")
        options = fault_options(run.faults, options)
    if options != scenario.fault_options:
        changes["fault_options"] = options
    return scenario.with_changes(**changes)


def _checked(run: RunParams, group: str, build: Callable[[], T]) -> T:
    keys = [k for k in run.values if k.startswith(tuple(group.split("/")))]
    try:
        return build()
    except ConfigError as exc:
        raise ConfigError(exc.detail, f"run {run.index}: {', '.join(keys) or group}: {exc.where}") from exc


def _spacecraft(params: SpacecraftParams, run: RunParams) -> SpacecraftParams:
    v, directions = run.values, run.directions
    changes: dict[str, object] = {}
    if "spacecraft.inertia_scale" in v or "spacecraft.inertia_offdiag" in v:
        J = inertia_tensor(params.bus_inertia, "bus_inertia").copy()
        mean_moment = float(np.trace(J)) / 3.0
        J[np.diag_indices(3)] *= v.get("spacecraft.inertia_scale", np.ones(3))
        for (i, j), d in zip(
            ((0, 1), (0, 2), (1, 2)), v.get("spacecraft.inertia_offdiag", np.zeros(3)), strict=True
        ):
            J[i, j] += d * mean_moment
            J[j, i] = J[i, j]
        changes["bus_inertia"] = tuple(map(tuple, J))
    tilt, offset = v.get("spacecraft.gimbal_misalignment_rad"), v.get("spacecraft.rotor_offset_m")
    if tilt is not None or offset is not None:
        units = []
        for i, u in enumerate(params.units):
            g, s = np.asarray(u.gimbal_axis, float), np.asarray(u.spin_axis, float)
            if tilt is not None:  # about a direction perpendicular to g: both axes turn, stay perpendicular
                az = directions["spacecraft.gimbal_misalignment_rad"][i]
                turn = so3.exp(tilt[i] * (math.cos(az) * s + math.sin(az) * np.cross(g, s)))
                g, s = turn @ g, turn @ s
            sigma = u.rotor_offset_m if offset is None else float(offset[i])
            units.append(replace(u, gimbal_axis=tuple(g), spin_axis=tuple(s), rotor_offset_m=sigma))
        changes["units"] = tuple(units)
    return replace(params, **changes) if changes else params  # type: ignore[arg-type]


def _phone(phone: PhoneSpec, v: Mapping[str, np.ndarray]) -> PhoneSpec:
    changes = {}
    for kind in SENSOR_KINDS:
        prefix = f"sensors.{kind}."
        fields = {k[len(prefix) :]: float(x[0]) for k, x in v.items() if k.startswith(prefix)}
        if fields:
            changes[kind] = replace(getattr(phone, kind), **fields)
    drawn = replace(phone, **changes) if changes else phone
    beyond = phone_out_of_range(drawn)  # the scenario file's own check, on the drawn phone
    if beyond is not None:  # the host would drop its readings: the run is an error saying so, not "lost"
        raise ConfigError(beyond[1], f"sensors.{beyond[0]}")
    return drawn


def _slew(slew: SlewScenario, run: RunParams) -> SlewScenario:
    """Start attitude turned by ``initial.angle_deg`` about a random axis; the commanded target (relative
    to the nominal start) from the dispersed slew angle and the tilted slew axis."""
    v, directions = run.values, run.directions
    R0 = np.asarray(slew.R0, float)
    turn = so3.log(R0.T @ np.asarray(slew.R_target, float))
    angle = float(np.linalg.norm(turn))
    axis = turn / angle if angle > 1e-12 else np.array([0.0, 0.0, 1.0])
    if "manoeuvre.axis_tilt_deg" in v:
        perp = _perpendicular(axis, float(directions["manoeuvre.axis_tilt_deg"][0]))
        axis = so3.exp(math.radians(float(v["manoeuvre.axis_tilt_deg"][0])) * perp) @ axis
    if "manoeuvre.angle_deg" in v:
        angle = math.radians(float(v["manoeuvre.angle_deg"][0]))
    start = R0
    if "initial.angle_deg" in v:
        start = R0 @ so3.exp(math.radians(float(v["initial.angle_deg"][0])) * directions["initial.angle_deg"])
    if not math.isfinite(angle):
        raise ConfigError(f"must be finite, got {angle!r}", "manoeuvre.angle_deg")
    return replace(slew, R0=start, R_target=R0 @ so3.exp(angle * axis))


def _perpendicular(axis: np.ndarray, azimuth: float) -> np.ndarray:
    """The unit vector perpendicular to ``axis`` at ``azimuth`` (rad) about it."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return math.cos(azimuth) * e1 + math.sin(azimuth) * np.cross(axis, e1)


# --------------------------------------------------------------------------- running a chunk
def run_chunk(scenario: Scenario, runs: Sequence[RunParams], trace_hz: float) -> list[RunResult]:
    """Run ``runs`` of ``scenario`` one after another through the runtime and return one result per run,
    in order; a run that fails (refused parameters, an error in its simulation) fails alone."""
    return [run_one(scenario, run, trace_hz) for run in runs]


def run_one(scenario: Scenario, run: RunParams, trace_hz: float) -> RunResult:
    """One run: :func:`realise`, then :func:`hil.runtime.run` in lockstep without a run directory (with
    faults drawn: :func:`run_faulted`), within its wall-time budget (:func:`wall_budget`, as a faulted
    run's: a run that hung held its whole campaign for ever, the worker's heartbeats going on from their
    own thread) — past it the run fails, ``RunHung``."""
    from hil.runtime import RunOptions
    from hil.runtime import run as run_scenario

    if run.faults is not None:
        return run_faulted(scenario, run, trace_hz)
    start = time.perf_counter()
    try:
        realised = realise(scenario, run)
        budget = WALL_BUDGET_S + WALL_PER_SIM_S * fault_bounds(realised).time_limit_s
        # a campaign counts failsafes and resets in its metrics
        with _quiet(_RUN_LOGGERS), wall_budget(budget):
            result = run_scenario(realised, RunOptions(out_root=None))
        if result.summary.get("exit") != "completed":
            raise HilError(f"the run did not complete: {result.summary.get('exit')}")
        trace = result.trace.arrays()
        failsafes = int(result.summary.get("failsafe_events", 0))
        metrics = run_metrics(trace, scenario.settle_deg, failsafes)
        samples = trace_length(scenario.slew.duration_s, trace_hz)
        decimated = decimated_trace(trace, trace_hz, samples)
    except Exception as exc:  # any error: recorded with the run, never lost
        return RunResult.failed(run, exc, time.perf_counter() - start)
    return RunResult(run.index, True, run.columns, metrics, decimated, wall_s=time.perf_counter() - start)


VIOLATION_COLUMNS: tuple[str, ...] = tuple(f"inv.{name}" for name in INVARIANTS)
"""A fault campaign's run's violations of each invariant: a count (a whole number >= 0) each."""
CHECK_COLUMNS: tuple[str, ...] = (
    "exit",
    *VIOLATION_COLUMNS,
    "inv.first",
    "detection.list",
    "recovery.list",
    "unseen",
)
"""A fault campaign's per-run columns: the run's exit reason, each invariant's violation count, the first
violation, each detected fault's latency (``kind:seconds;...``), each outage's recovery time, and the
faults the host could not have seen (masked by another, too close to the end)."""


def run_faulted(scenario: Scenario, run: RunParams, trace_hz: float) -> RunResult:
    """A run with drawn faults (:mod:`.fault_plan`): the board's and the world's faults in its scenario,
    the operator's commands on the control tick, everything it recorded kept
    (:class:`~hil.runtime.record.RunRecorder`) and its invariants checked
    (:func:`~hil.runtime.invariants.check_run`). A run that did not complete is not a failed run here —
    whether it said so honestly is an invariant; a failed run is one whose record cannot be had."""
    from hil.runtime import RunOptions
    from hil.runtime import run as run_scenario

    assert run.faults is not None
    start = time.perf_counter()
    try:
        realised = realise(scenario, run)
    except Exception as exc:
        return RunResult.failed(run, exc, time.perf_counter() - start)
    recorder = RunRecorder(realised.n_units)
    schedule = operator_schedule(run.faults)
    observer = Observers(recorder, ScheduledOperator(schedule)) if schedule else recorder
    error: str | None = None
    bounds = fault_bounds(realised)
    budget = WALL_BUDGET_S + WALL_PER_SIM_S * bounds.time_limit_s
    try:
        with _quiet(_RUN_LOGGERS, logging.CRITICAL), wall_budget(budget):
            result = run_scenario(
                realised, RunOptions(out_root=None, observer=observer, rows_to_observer=True)
            )
        summary = result.summary
    except Exception as exc:  # a crash is what the invariants look for: recorded with the run
        error = describe(exc)
        summary = recorder.summary
        result = None
    _explain_a_run_too_short(recorder, realised)
    report = check_run(run.faults, recorder, bounds, error)
    checks = _checks(summary, report)
    wall = time.perf_counter() - start
    if result is None:
        return RunResult.failed(run, error or "no record", wall, checks)
    trace = result.trace.arrays()
    metrics: dict[str, float] = dict.fromkeys(METRICS, math.nan)
    if len(trace["t"]):
        metrics = run_metrics(trace, scenario.settle_deg, int(summary.get("failsafe_events", 0)))
    samples = trace_length(scenario.slew.duration_s, trace_hz)
    decimated = np.full((len(TRACES), samples), np.nan, dtype=np.float32)
    if len(trace["t"]):
        decimated = decimated_trace(trace, trace_hz, samples)
    return RunResult(run.index, True, run.columns, metrics, decimated, wall_s=wall, checks=checks)


def _explain_a_run_too_short(recorder: RunRecorder, scenario: Scenario) -> None:
    """A requirement missed with nothing in the record to explain it is ``back_in_control``'s violation
    — unless the run was too short for its slew to settle (:meth:`Scenario.time_to_judge`: a campaign
    run with ``--duration 20`` on a slew that needs 28.5 s): then the miss is the duration's, not the
    system's, and the recorded requirement says so (``explained``, with the reason in ``why``) rather than
    every run of the campaign reporting a violation. A run long enough is judged as before."""
    requirement = recorder.summary.get("requirement")
    if not isinstance(requirement, Mapping) or requirement.get("met") or requirement.get("explained"):
        return
    shortfall = scenario.time_to_judge().shortfall(scenario.slew.duration_s)
    if shortfall is None:
        return
    # its why was "nothing in the record explains it": the record's length does
    recorder.summary["requirement"] = {**requirement, "why": f"not judged: {shortfall}", "explained": True}


WALL_BUDGET_S = 120.0
WALL_PER_SIM_S = 2.0
"""A faulted run's wall-clock budget: this much, plus this many wall seconds per simulated second of its
time limit (a lockstep run goes 20-30x faster than real time: the budget only catches a loop that stopped
advancing simulated time)."""


@contextlib.contextmanager
def wall_budget(seconds: float, again_s: float = 1.0) -> Iterator[None]:
    """Raise :class:`~protocol.errors.RunHung` in this thread if the block is still running after
    ``seconds`` of wall time (at its next Python bytecode: a compiled kernel that never returns is not
    caught), and again every ``again_s`` while it still runs. A block that went past its budget fails
    ``RunHung`` however it ends: the exception, raised wherever the thread is, can be caught on the way
    (an ``except Exception`` that logs and goes on, importlib's ``except OSError`` when it was an OSError)
    — such a run once finished "ok" past a budget of 6 ms. One still pending as the block ends is
    withdrawn, never raised after it."""
    thread = ctypes.c_ulong(threading.get_ident())
    lock = threading.Lock()
    state = {"done": False, "fired": False}
    ended = threading.Event()

    def watch() -> None:
        wait = seconds
        while not ended.wait(wait):
            with lock:
                if state["done"]:
                    return
                state["fired"] = True
                ctypes.pythonapi.PyThreadState_SetAsyncExc(thread, ctypes.py_object(RunHung))
            wait = again_s

    watcher = threading.Thread(target=watch, name="wall-budget", daemon=True)
    watcher.start()
    try:
        yield
    except BaseException as exc:
        if not _end_watch(lock, state, ended, thread):
            raise
        if isinstance(exc, RunHung):  # the interrupt itself, raised as a bare class: said with its budget
            raise RunHung(f"past its wall budget of {seconds:g} s") from None
        raise RunHung(f"past its wall budget of {seconds:g} s, then {describe(exc)}") from exc
    if _end_watch(lock, state, ended, thread):
        raise RunHung(f"past its wall budget of {seconds:g} s (its interrupt was caught on the way)")


def _end_watch(lock: threading.Lock, state: dict[str, bool], ended: threading.Event, thread: Any) -> bool:
    """End :func:`wall_budget`'s watch; whether it fired. An interrupt it left pending is withdrawn, and
    one that lands here before the watch is ended is taken as the firing it is."""
    while True:
        try:
            with lock:
                state["done"] = True
                if state["fired"]:
                    ctypes.pythonapi.PyThreadState_SetAsyncExc(thread, None)  # NULL: clear a pending one
            ended.set()
            return state["fired"]
        except RunHung:
            continue


def fault_bounds(scenario: Scenario) -> Bounds:
    """The bounds a fault campaign holds ``scenario``'s runs to (:class:`~hil.runtime.invariants.Bounds`)."""
    from hil.link.board.config import ClientConfig
    from hil.runtime.faults import RECOVER_WITHIN_S, STALE_AFTER_S
    from hil.runtime.loop import SPINUP_ALLOWANCE_S
    from hil.scenario.reader import DEFAULT_LINK_TIMEOUT_S

    loop = scenario.loop
    phone = scenario.phone
    slowest = 1.0 / min(phone.gyr.rate_hz, phone.acc.rate_hz, phone.mag.rate_hz)
    limit = loop.warmup_s + scenario.slew.duration_s + SPINUP_ALLOWANCE_S + RECOVER_WITHIN_S
    return Bounds(
        stale_after_s=STALE_AFTER_S,
        tick_s=1.0 / loop.control_rate_hz,
        telemetry_s=1.0 / float(scenario.board_options.get("telemetry_rate", 20.0)),
        phone_period_s=slowest,
        reconnect_max_s=ClientConfig().reconnect_max_s,
        recover_within_s=RECOVER_WITHIN_S,
        time_limit_s=limit,
        nominal_rotor=scenario.spacecraft.nominal_rotor_speed,
        duration_s=scenario.slew.duration_s,
        link_timeout_s=float(scenario.board_options.get("link_timeout", DEFAULT_LINK_TIMEOUT_S)),
        mcu_watchdog_s=float(scenario.board_options.get("mcu_watchdog", Bounds.mcu_watchdog_s)),
        rotors_sensed=board_of(scenario) != "firmware",
    )


def exit_kind(reason: str) -> str:
    """A run's exit reason without its particulars (times, causes): ``completed``, ``lost``, ``aborted``,
    ``disarmed by the operator``, ``interrupted``, ``error``, ``time limit`` — what a campaign counts."""
    for kind in ("disarmed by the operator", "time limit", "interrupted"):
        if reason.startswith(kind):
            return kind
    return reason.split(":")[0]


def _checks(summary: Mapping[str, Any], report: InvariantReport) -> dict[str, Any]:
    out: dict[str, Any] = {"exit": exit_kind(str(summary.get("exit", ""))) if summary else "crashed"}
    for name, count in report.counts.items():
        out[f"inv.{name}"] = count
    out["inv.first"] = report.first()
    out["detection.list"] = ";".join(f"{k}:{v:.4f}" for k, v in report.detection)
    out["recovery.list"] = ";".join(f"{k}:{v:.4f}" for k, v in report.recovery)
    out["unseen"] = ";".join(report.unseen)
    return out


_RUN_LOGGERS = (
    "hil.runtime.host",
    "hil.runtime.watch",
    "hil.runtime.actuators",
    "hil.link.board.session",
    "hil.estimation.multirate",
)
"""What warns about a run's failsafes and resets on the console (``hil run`` wants that, a campaign of
hundreds of runs does not: its metrics count them)."""


@contextlib.contextmanager
def _quiet(names: Sequence[str], level: int = logging.ERROR) -> Iterator[None]:
    """Those loggers' records below ``level`` off for the block (by default errors still show; a fault
    campaign's run records its faults and errors, and checks them)."""
    loggers = [logging.getLogger(name) for name in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(level)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)
