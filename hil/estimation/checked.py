"""A user's estimator, held to its interface: :class:`CheckedEstimator` wraps an estimator that another
package registered (:mod:`hil.estimation.registry` builds every estimator but ``hil``'s own variational
one through it), so that whatever it does wrong mid-run ends the run with a
:class:`~hil.plugins.PluginError` naming it and the step — never a NaN steered on, a traceback from deep in
the controller, or a replay scored on half its rows.

What is checked, each call (a few µs a step):

=========================  ========================================================================
call                       checked
=========================  ========================================================================
``step(s)``                an :class:`~hil.estimation.estimator.Estimate` (or an object with its six
                           attributes: ``t`` a real number, ``flags`` and ``iterations`` integers, the
                           arrays of integers or floats), at ``s.t``; ``R``, ``omega``, ``omega_err``
                           finite; ``R`` a rotation (``|R Rᵀ − I| ≤`` :data:`ORTHONORMAL_TOL`
                           entrywise, det > 0);
                           each axis of ``omega`` and ``omega_err`` within :data:`RATE_LIMIT`;
                           ``flags`` of :class:`~hil.estimation.sensors.StepFlag`'s bits only,
                           ``iterations`` a count from 0 to :data:`MAX_ITERATIONS`
``run(steps)``             an :class:`~hil.estimation.estimator.EstimateBatch` of ``len(steps)`` rows
                           at ``steps.t``, each row as a step's; ``steps``' arrays are passed read-only
                           (an estimator that wrote into them changed what the replay then scores)
``gyro_bias``              a finite 3-vector of integers or floats, each axis within :data:`RATE_LIMIT`
``set_gyro_bias(b)``       given a copy of ``b`` (the host's own is not the estimator's to change)
=========================  ========================================================================

Anything the estimator raises (its own exception, Python's, a ``sys.exit()``), in its calls or as what it
returned is read (a property, an ``__array__``), becomes a :class:`~hil.plugins.PluginError` ``from`` it
(:func:`~hil.plugins.call_plugin`); Ctrl-C (KeyboardInterrupt) passes through.

Its live calls (``step``, ``gyro_bias``, ``set_gyro_bias``, ``set_rest_learning``: the host's, mid-run) run,
in a run, on a thread of the estimator's own and are waited for a bounded wall time
(:class:`~hil.plugin_worker.PluginWorker`, installed by the run: :meth:`CheckedEstimator.run_calls_with`),
:func:`step_bound_s`: :data:`STEP_WAIT_PERIODS` of the site's sample period, never less than
:data:`STEP_WAIT_FLOOR_S` (:data:`FIRST_CALL_WAIT_S` for its first step); one that does not return is a
:class:`~hil.plugins.PluginTimeout` naming the call and the step's time. Wall time in lockstep too: the
simulated clock stands still while the host waits, so only the wall clock can tell a step that never returns.
``run`` (a replay's batch) goes through the same calls, waited for :func:`run_bound_s` of its number of
steps: a batch that never returned hung ``hil replay`` until it was killed. No I/O."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import fields, replace
from numbers import Integral, Real
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation.admission import ReadingLimits
from hil.estimation.sensors import StepFlag
from hil.plugins import PluginError, call_plugin, describe_value

if TYPE_CHECKING:
    from hil.estimation.estimator import Estimate, EstimateBatch
    from hil.estimation.interface import Estimator
    from hil.estimation.sensors import MergedStep, MergedSteps

Array = NDArray[np.float64]

ORTHONORMAL_TOL = 1e-6
"""How far from a rotation an estimate's ``R`` may be: each entry of ``R Rᵀ − I`` (a float32 estimator's
rounding is ~1e-7; a quaternion integrated without renormalising drifts past it within minutes)."""

RATE_LIMIT = ReadingLimits.gyr
"""The largest ``omega`` or ``omega_err`` on any axis an estimate may give (rad/s): the admission's
gyroscope bound (a phone's ±2000 °/s with a margin). A finite rate beyond it is no estimate of a
spacecraft's motion: 1e300 rad/s was steered on into a NaN setpoint naming nobody, 1000 rad/s into a run
"completed" 114° off its target."""

TIME_TOL_S = 1e-9
"""How far an estimate's ``t`` may be from its step's (s)."""

MAX_ITERATIONS = 2**31 - 1
"""The most ``iterations`` one step may say it took (a count, ≥ 0): the replay keeps them, and the flags,
as int64 arrays; 2**70 passed the check and ended ``hil replay`` with a raw OverflowError after the whole
log was estimated (the paper's estimator takes at most ``newton_max_iter``, 10 by default)."""

KNOWN_FLAGS = sum(map(int, StepFlag))
"""Every :class:`~hil.estimation.sensors.StepFlag` bit: the only ones an estimate may set (a bit beyond
them is no condition the run can count; bit 70 ended ``hil replay`` with a raw OverflowError)."""

STEP_WAIT_FLOOR_S = 30.0
"""s of wall time: the least a user's estimator's live call is waited for before it is taken to have hung.
Far above any honest step: a Python step takes ~10-100 µs, a GC pause or a loaded machine's scheduling a
few ms to 100 ms; a few seconds is a machine swapping. The run cannot go on without the estimate either way,
so the bound only has to tell "never" from "late" (and the board's own link watchdog fails it safe within
its timeout meanwhile, in real time)."""

STEP_WAIT_PERIODS = 1000
"""How many of the site's sample periods a live call is waited for, where that is longer than
:data:`STEP_WAIT_FLOOR_S` (a slow log's steps: 1 Hz is 1000 s)."""

FIRST_CALL_WAIT_S = 300.0
"""s of wall time: the bound of an estimator's first step, which may compile its kernels (numba JIT:
tens of seconds on a loaded machine, as ``hil``'s own kernels take after an install)."""


def step_bound_s(period_s: float | None) -> float:
    """The wall time (s) a live call of an estimator stepping every ``period_s`` (s; None or not a positive
    finite number: unknown) is waited for: :data:`STEP_WAIT_PERIODS` periods, at least
    :data:`STEP_WAIT_FLOOR_S`."""
    if period_s is None or not (math.isfinite(period_s) and period_s > 0):
        return STEP_WAIT_FLOOR_S
    return max(STEP_WAIT_FLOOR_S, STEP_WAIT_PERIODS * period_s)


RUN_WAIT_PER_STEP_S = 0.01
"""s of wall time per step a batch ``run`` is waited for, on top of :data:`FIRST_CALL_WAIT_S` (its kernels
may compile first): a hundred times a slow Python step (~100 µs), so a machine swapping is waited for and a
run that never returns is told apart — 400 000 steps (:data:`hil.logs.replay.MAX_REPLAY_STEPS`) ~70 min."""


def run_bound_s(n_steps: int) -> float:
    """The wall time (s) a batch ``run`` over ``n_steps`` steps is waited for: :data:`FIRST_CALL_WAIT_S`
    and :data:`RUN_WAIT_PER_STEP_S` a step."""
    return FIRST_CALL_WAIT_S + RUN_WAIT_PER_STEP_S * max(int(n_steps), 0)


_REAL_KINDS = "iuf"
"""The numpy dtype kinds an estimate's arrays may have: integers and floats (not booleans, complex numbers,
text or objects)."""

_FIFTEEN = struct.Struct("=15d").unpack_from  # an Estimate's kept bytes: R row-major, omega, omega_err
_FIELDS = ("t", "R", "omega", "omega_err", "flags", "iterations")
_NAMES = ("R",) * 9 + ("omega",) * 3 + ("omega_err",) * 3  # what each of the fifteen is


def rotation_fault(r: tuple[float, ...]) -> str | None:
    """Why the row-major 3×3 ``r`` (9 floats) is not a rotation (:data:`ORTHONORMAL_TOL`), or None."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    worst = max(
        abs(r0 * r0 + r1 * r1 + r2 * r2 - 1.0),
        abs(r3 * r3 + r4 * r4 + r5 * r5 - 1.0),
        abs(r6 * r6 + r7 * r7 + r8 * r8 - 1.0),
        abs(r0 * r3 + r1 * r4 + r2 * r5),
        abs(r0 * r6 + r1 * r7 + r2 * r8),
        abs(r3 * r6 + r4 * r7 + r5 * r8),
    )
    if not worst <= ORTHONORMAL_TOL:
        return f"R is not orthonormal (|R Rᵀ − I| = {worst:.3g} > {ORTHONORMAL_TOL:g})"
    det = r0 * (r4 * r8 - r5 * r7) - r1 * (r3 * r8 - r5 * r6) + r2 * (r3 * r7 - r4 * r6)
    if not det > 0:
        return f"R is a reflection (det R = {det:.6g}), not a rotation"
    return None


def counts_fault(flags: int, iterations: int) -> str | None:
    """Why an estimate's ``flags`` and ``iterations`` (ints) are not a step's, or None: flags of bits no
    :class:`~hil.estimation.sensors.StepFlag` has (:data:`KNOWN_FLAGS`), or a count of iterations below
    0 or beyond :data:`MAX_ITERATIONS`."""
    if not 0 <= flags <= KNOWN_FLAGS or flags & ~KNOWN_FLAGS:
        return f"flags {int(flags):#x}, bits no StepFlag has (known: {KNOWN_FLAGS:#x})"
    if not 0 <= iterations <= MAX_ITERATIONS:
        return f"iterations {int(iterations)}, not a count from 0 to {MAX_ITERATIONS}"
    return None


BoundedCalls = Callable[[str, Callable[[], Any], float], Any]
"""How a :class:`CheckedEstimator` makes a live call: ``calls(what, call, bound_s)`` returns ``call()``'s
result, or raises (:class:`~hil.plugins.PluginTimeout` once ``bound_s`` of wall time has passed)."""


def _called_directly(what: str, call: Callable[[], Any], bound_s: float) -> Any:
    """A live call made in the caller's thread, unbounded: the default, where no run installed a worker."""
    return call()


class CheckedEstimator:
    """``inner``, a user's :class:`~hil.estimation.interface.Estimator`, with every call checked (see the
    module docstring); ``name`` is its registered name, for the errors; ``period_s`` its site's sample
    period (s), for the bound of its live calls (:func:`step_bound_s`)."""

    __slots__ = ("inner", "name", "plugin", "bound_s", "_calls", "_stepped")

    def __init__(self, inner: Estimator, name: str, period_s: float | None = None) -> None:
        self.inner = inner
        self.name = name
        self.plugin = f"estimator {name!r}"
        self.bound_s = step_bound_s(period_s)
        self._calls: BoundedCalls = _called_directly
        self._stepped = False

    def __repr__(self) -> str:
        return f"CheckedEstimator({self.inner!r}, {self.name!r})"

    def _error(self, detail: str) -> PluginError:
        return PluginError(self.plugin, detail)

    def _call(self, what: str, call: Callable[[], Any]) -> Any:
        return call_plugin(self.plugin, what, call)

    def run_calls_with(self, calls: BoundedCalls) -> None:
        """Make the host's mid-run calls through ``calls`` (``calls(what, call, bound_s)``: the run's
        :meth:`hil.plugin_worker.PluginWorker.call`, a thread waited for ``bound_s``); by default they are
        made directly (this package starts no thread)."""
        self._calls = calls

    def _live(self, what: str, call: Callable[[], Any], bound_s: float | None = None) -> Any:
        """``call()``, one of the host's mid-run calls, through :meth:`run_calls_with`'s ``calls``, waited
        for ``bound_s`` (s; default :attr:`bound_s`)."""
        bound = self.bound_s if bound_s is None else bound_s
        return call_plugin(self.plugin, what, lambda: self._calls(what, call, bound))

    # ------------------------------------------------------------------ live
    def step(self, s: MergedStep) -> Estimate:
        bound = self.bound_s if self._stepped else max(self.bound_s, FIRST_CALL_WAIT_S)
        self._stepped = True
        out = self._live(f"step at t = {s.t!r} s", lambda: self.inner.step(s), bound)
        return self.checked_estimate(out, s.t)

    def checked_estimate(self, out: Any, t: float) -> Estimate:
        """``out``, what the estimator's step at ``t`` returned, as an Estimate if it is a valid one."""
        from hil.estimation.estimator import Estimate

        where = f"step at t = {t!r} s"
        if not (
            type(out) is Estimate
            and len(out) == 4
            and type(out[0]) is float
            and type(out[1]) is StepFlag
            and type(out[2]) is int
            and type(out[3]) is bytes
            and len(out[3]) == 120
        ):  # anything else, an Estimate tuple built by hand too (struct.error), is read by its attributes
            out = self._call(f"{where}: reading what it returned", lambda: self._as_estimate(out, where))
        values = _FIFTEEN(out[3])
        if not all(map(math.isfinite, values)):
            bad = sorted({_NAMES[i] for i, v in enumerate(values) if not math.isfinite(v)})
            raise self._error(f"{where} returned a non-finite {' and '.join(bad)}")
        fastest = max(map(abs, values[9:]))
        if not fastest <= RATE_LIMIT:
            name = _NAMES[9 + list(map(abs, values[9:])).index(fastest)]
            raise self._error(
                f"{where} returned {name} of {fastest:.6g} rad/s on an axis, beyond any spacecraft's "
                f"(the gyroscope's bound, {RATE_LIMIT:g} rad/s)"
            )
        fault = rotation_fault(values[:9])
        if fault is not None:
            raise self._error(f"{where} returned an attitude that is not a rotation: {fault}")
        est_t = out[0]
        if not (isinstance(est_t, (int, float)) and abs(est_t - t) <= TIME_TOL_S):
            raise self._error(f"{where} returned an estimate at t = {est_t!r}, not the step's")
        fault = counts_fault(out[1], out[2])
        if fault is not None:
            raise self._error(f"{where} returned {fault}")
        return out  # type: ignore[no-any-return]

    def _as_estimate(self, out: Any, where: str) -> Estimate:
        """``out`` read through its six attributes as an Estimate (anything its reading raises beyond what
        is said here is the caller's :func:`~hil.plugins.call_plugin`'s)."""
        from hil.estimation.estimator import Estimate

        missing = [name for name in _FIELDS if not hasattr(out, name)]
        if missing:
            got = describe_value(out)
            raise self._error(f"{where} returned {got}, not an Estimate (no {', '.join(missing)})")
        shapes = {"R": (3, 3), "omega": (3,), "omega_err": (3,)}
        try:
            given = {k: np.asarray(getattr(out, k)) for k in shapes}
            kinds = [f"{k} of dtype {a.dtype}" for k, a in given.items() if a.dtype.kind not in _REAL_KINDS]
            if kinds:  # float() of them dropped a complex part, read text and booleans as numbers
                raise self._error(f"{where} returned {', '.join(kinds)}; wants real numbers")
            arrays = {k: a.astype(float) for k, a in given.items()}
            bad = [f"{k} {a.shape}" for k, a in arrays.items() if a.shape != shapes[k]]
            if bad:
                raise self._error(f"{where} returned shapes {', '.join(bad)}; wants R (3, 3), omega (3,)")
            t, flags, iterations = out.t, out.flags, out.iterations
            if isinstance(t, bool) or not isinstance(t, Real):
                raise self._error(f"{where} returned t {describe_value(t)}, not a number of seconds")
            for key, value in (("flags", flags), ("iterations", iterations)):
                if isinstance(value, bool) or not isinstance(value, Integral):  # int() truncated 1.5 to a bit
                    raise self._error(f"{where} returned {key} {describe_value(value)}, not an integer")
            flags, iterations = int(flags), int(iterations)
            fault = counts_fault(flags, iterations)  # before StepFlag(): it reads -1 as every bit set
            if fault is not None:
                raise self._error(f"{where} returned {fault}")
            return Estimate(
                float(t), arrays["R"], arrays["omega"], arrays["omega_err"], StepFlag(flags), iterations
            )
        except PluginError:
            raise
        except (TypeError, ValueError, OverflowError) as exc:
            raise self._error(f"{where} returned an estimate of the wrong types: {exc}") from exc

    # ------------------------------------------------------------------ batch
    def run(self, steps: MergedSteps, progress: Callable[[int, int], None] | None = None) -> EstimateBatch:
        given = _read_only(steps)
        where = f"run over {len(steps)} steps"
        out = self._live(where, lambda: self.inner.run(given, progress), run_bound_s(len(steps)))
        return self._call(f"{where}: reading what it returned", lambda: self.checked_batch(out, steps))  # type: ignore[no-any-return]

    def checked_batch(self, out: Any, steps: MergedSteps) -> EstimateBatch:
        """``out``, what the estimator's run over ``steps`` returned, if it is a valid batch for them."""
        from hil.estimation.estimator import EstimateBatch

        n = len(steps)
        where = f"run over {n} steps"
        if not isinstance(out, EstimateBatch):
            raise self._error(f"{where} returned {describe_value(out)}, not an EstimateBatch")
        shapes = {
            "t": (n,),
            "R": (n, 3, 3),
            "omega": (n, 3),
            "omega_err": (n, 3),
            "flags": (n,),
            "iterations": (n,),
        }
        for key, shape in shapes.items():
            a = getattr(out, key)
            if not isinstance(a, np.ndarray) or a.shape != shape:
                got = a.shape if isinstance(a, np.ndarray) else type(a).__name__
                raise self._error(f"{where} returned {key} of shape {got}; wants {shape}")
        for key in ("t", "R", "omega", "omega_err"):
            a = getattr(out, key)
            if not np.issubdtype(a.dtype, np.floating):
                raise self._error(f"{where} returned {key} of dtype {a.dtype}; wants floats")
            finite = np.isfinite(a.reshape(n, -1)).all(axis=1)
            if not finite.all():
                i = int(np.flatnonzero(~finite)[0])
                raise self._error(
                    f"{where} returned a non-finite {key} at step {i} (t = {float(steps.t[i])!r} s): "
                    f"{int(n - finite.sum())} of {n} rows"
                )
            if key in ("omega", "omega_err"):
                beyond = ~(np.abs(a).max(axis=1, initial=0.0) <= RATE_LIMIT)
                if beyond.any():
                    i = int(np.flatnonzero(beyond)[0])
                    raise self._error(
                        f"{where} returned {key} of {float(np.abs(a[i]).max()):.6g} rad/s on an axis at step "
                        f"{i} (t = {float(steps.t[i])!r} s), beyond any spacecraft's (the gyroscope's "
                        f"bound, {RATE_LIMIT:g} rad/s)"
                    )
        off = np.abs(out.t - steps.t) > TIME_TOL_S
        if off.any():
            i = int(np.flatnonzero(off)[0])
            raise self._error(
                f"{where} returned t[{i}] = {float(out.t[i])!r}, not the step's {float(steps.t[i])!r}"
            )
        R = out.R
        gram = np.abs(np.einsum("nij,nkj->nik", R, R) - np.eye(3)).reshape(n, 9).max(axis=1, initial=0.0)
        bad = ~(gram <= ORTHONORMAL_TOL) | ~(np.linalg.det(R) > 0)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            fault = rotation_fault(tuple(float(v) for v in R[i].reshape(9)))
            raise self._error(
                f"{where} returned an attitude that is not a rotation at step {i} "
                f"(t = {float(steps.t[i])!r} s): {fault}"
            )
        if not (
            np.issubdtype(out.flags.dtype, np.integer) and np.issubdtype(out.iterations.dtype, np.integer)
        ):
            raise self._error(f"{where} returned flags or iterations that are not integers")
        # ranges first (a uint64 dtype takes no negative mask), then the bits of the flags within range
        off = ~((out.flags >= 0) & (out.flags <= KNOWN_FLAGS))
        off |= (np.where(off, 0, out.flags).astype(np.int64) & ~KNOWN_FLAGS) != 0
        off |= ~((out.iterations >= 0) & (out.iterations <= MAX_ITERATIONS))
        if off.any():
            i = int(np.flatnonzero(off)[0])
            fault = counts_fault(int(out.flags[i]), int(out.iterations[i]))
            raise self._error(f"{where} returned at step {i} (t = {float(steps.t[i])!r} s) {fault}")
        return out

    # ------------------------------------------------------------------ bias and rest
    @property
    def gyro_bias(self) -> Array:
        b = self._live("gyro_bias", lambda: self.inner.gyro_bias)
        return self._call("gyro_bias: reading what it returned", lambda: self._bias(b))  # type: ignore[no-any-return]

    def _bias(self, b: Any) -> Array:
        try:
            given = np.asarray(b)
        except (TypeError, ValueError) as exc:
            raise self._error(f"gyro_bias is {describe_value(b)}, not a 3-vector") from exc
        if given.dtype.kind not in _REAL_KINDS:  # a float() of it dropped a complex part, read "0.1" as 0.1
            raise self._error(f"gyro_bias is {describe_value(b)} of dtype {given.dtype}; wants real numbers")
        a = given.astype(float)  # a copy: the estimator's own is not the host's to keep
        if a.shape != (3,) or not np.isfinite(a).all():
            raise self._error(f"gyro_bias is {describe_value(b)}, not a finite 3-vector (rad/s)")
        if not np.abs(a).max() <= RATE_LIMIT:  # written to events.jsonl as what the estimator found
            raise self._error(
                f"gyro_bias is {describe_value(b)}, beyond any gyroscope's bound ({RATE_LIMIT:g} rad/s)"
            )
        return a

    def set_gyro_bias(self, bias: ArrayLike) -> None:
        given = np.array(bias, dtype=float)  # a copy: the caller's is not the estimator's to change
        self._live("set_gyro_bias", lambda: self.inner.set_gyro_bias(given))

    def set_rest_learning(self, enabled: bool) -> None:
        self._live("set_rest_learning", lambda: self.inner.set_rest_learning(enabled))


def _read_only(steps: MergedSteps) -> MergedSteps:
    """``steps`` with read-only views of its arrays (the caller's stay writable)."""
    views: dict[str, Any] = {}
    for f in fields(steps):
        a = getattr(steps, f.name)
        if isinstance(a, np.ndarray):
            a = a.view()
            a.flags.writeable = False
        views[f.name] = a
    return replace(steps, **views)
