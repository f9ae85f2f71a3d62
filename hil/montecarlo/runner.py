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
import logging
import math
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from hil import so3
from hil.scenario import Scenario
from hil.scenario.config import SlewScenario
from hil.simulation.phone import PhoneSpec
from hil.vscmg import SpacecraftParams
from hil.vscmg.params import inertia_tensor
from protocol.errors import ConfigError, HilError

from .dispersions import SENSOR_KINDS, RunParams
from .metrics import decimated_trace, run_metrics, trace_length

T = TypeVar("T")


@dataclass(frozen=True)
class RunResult:
    """One finished run: ``ok`` with its ``metrics`` (:data:`~.metrics.METRICS`) and ``trace`` (see
    :func:`~.metrics.decimated_trace`), or failed with ``error`` ("ExceptionType: message"). ``columns``
    are its drawn parameters (always, so a failed run can be reproduced and looked into); ``wall_s`` its
    share of the chunk's compute time."""

    index: int
    ok: bool
    columns: Mapping[str, float | int | str]
    metrics: Mapping[str, float]
    trace: NDArray[np.float32] | None
    error: str = ""
    wall_s: float = 0.0

    @classmethod
    def failed(cls, run: RunParams, error: BaseException | str, wall_s: float = 0.0) -> RunResult:
        text = error if isinstance(error, str) else describe(error)
        return cls(run.index, False, run.columns, {}, None, text, wall_s)


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
    if run.outages:
        stalls = scenario.fault_options.get("stall", [])
        stalls = list(stalls) if isinstance(stalls, list) else [stalls]
        stalls += [f"{start!r}:{duration!r}" for start, duration in run.outages]
        changes["fault_options"] = {**scenario.fault_options, "stall": stalls}
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
    return replace(phone, **changes) if changes else phone


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
    """One run: :func:`realise`, then :func:`hil.runtime.run` in lockstep without a run directory."""
    from hil.runtime import RunOptions
    from hil.runtime import run as run_scenario

    start = time.perf_counter()
    try:
        realised = realise(scenario, run)
        with _quiet(_RUN_LOGGERS):  # a campaign counts failsafes and resets in its metrics
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


_RUN_LOGGERS = ("hil.runtime.host", "hil.link.board.session")
"""What warns about a run's failsafes and resets on the console (``hil run`` wants that, a campaign of
hundreds of runs does not: its metrics count them)."""


@contextlib.contextmanager
def _quiet(names: Sequence[str]) -> Iterator[None]:
    """Those loggers' warnings off for the block (errors still show)."""
    loggers = [logging.getLogger(name) for name in names]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)
