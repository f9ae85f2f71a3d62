"""The paper's variational estimator as an object: :class:`VariationalEstimator` takes one sample at a
time (:meth:`~VariationalEstimator.update`) or a batch of merged steps
(:meth:`~VariationalEstimator.update_batch`), with its state snapshot (:class:`EstimatorState`), counters
(:class:`EstimatorStats`) and outputs (:class:`Estimate`, :class:`EstimateBatch`). Pure math, no I/O.

The scheme itself (equations, Newton solve, missing measurements, long steps) is documented and implemented
in :mod:`hil.estimation.variational` as compiled kernels on a state array and a parameter array (their
layouts are there): the object holds those arrays and makes one compiled call per sample or per batch.
Its parameters are in :mod:`hil.estimation.params`.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from operator import itemgetter

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import jit, so3
from hil.estimation import variational as k
from hil.estimation.params import EstimatorParams
from hil.estimation.quaternions import quats_of
from hil.estimation.sensors import MergedSteps, StepFlag, as_vec3
from hil.estimation.slots import MAX_SUBSTEPS, NEWTON_FAILED
from hil.so3.floats import Mat9, Vec3
from protocol.errors import ConfigError, ConvergenceError

Array = NDArray[np.float64]

_NAN3 = (math.nan, math.nan, math.nan)
_FLAGS: dict[int, StepFlag] = {}

ESTIMATE_SIZE = 15
"""Floats at the head of the estimator's state that an :class:`Estimate` holds: R̂ row-major, Ω̂, ω."""

# The kernels' layout constants, bound once for the per-sample path (a module attribute costs a lookup).
_S_T, _FLAG_BITS, _ITER_SHIFT = k.S_T, k.FLAG_BITS, k.ITER_SHIFT
_new_tuple = tuple.__new__
_unpack_twelve = struct.Struct("=12d").unpack_from  # R row-major and omega, native float64 as numpy's
_SEQUENCES = (list, tuple)


@dataclass(frozen=True)
class EstimatorState:
    """A snapshot of the estimator, enough to resume it exactly (``VariationalEstimator.restore``).

    ``t`` s since the first sample; ``R`` (3, 3) body → inertial; ``omega_err`` (3,) rad/s the rate-estimate
    error ω (``Ω̂ = Ω^m − ω``); ``gyr`` (3,) rad/s the last rate measurement Ω^m[i] used; ``torque`` (3,) the
    cached ``Φ'(U⁰[i]) S_L[i]``; ``started`` whether a first sample has been taken; ``bias`` (3,) rad/s the
    gyro bias estimate b̂ (``Ω̂ = Ω^m − b̂ − ω``).
    """

    t: float
    R: Array
    omega_err: Array
    gyr: Array
    torque: Array
    started: bool
    bias: Array = field(default_factory=lambda: np.zeros(3))


@dataclass(frozen=True)
class EstimatorStats:
    """Counters since construction (or the last ``reset``)."""

    steps: int = 0
    newton_failures: int = 0
    newton_updates: int = 0
    max_newton_updates: int = 0
    substeps: int = 0
    degenerate: int = 0
    no_direction: int = 0
    gyro_missing: int = 0


class Estimate(tuple):  # type: ignore[type-arg]
    """The estimator's output for one sample: ``t`` s, ``R`` (3, 3) body → inertial (ENU), ``omega`` (3,)
    rad/s the body rate estimate Ω̂, ``omega_err`` (3,) rad/s ω, ``flags``, Newton ``iterations`` taken.

    Immutable (a tuple underneath). The live path builds one for every sample, so it holds the estimate's
    15 floats as the bytes of one float64 array (``R`` row-major, ``omega``, ``omega_err``) and makes ``R``,
    ``omega`` and ``omega_err`` as read-only arrays over them when they are read: ~0.25 µs a sample instead
    of ~1 µs for three arrays and a frozen dataclass (the host reads one estimate in several; bytes are
    taken from the state in a third of an array copy's time). The live path builds it with
    :func:`estimate`, from the state's head."""

    __slots__ = ()

    def __new__(
        cls, t: float, R: ArrayLike, omega: ArrayLike, omega_err: ArrayLike, flags: StepFlag, iterations: int
    ) -> Estimate:
        parts = (
            np.asarray(R, dtype=float).reshape(9),
            np.asarray(omega, dtype=float).reshape(3),
            np.asarray(omega_err, dtype=float).reshape(3),
        )
        return tuple.__new__(cls, (t, flags, iterations, np.concatenate(parts).tobytes()))

    t: float = property(itemgetter(0))  # type: ignore[assignment]
    flags: StepFlag = property(itemgetter(1))  # type: ignore[assignment]
    iterations: int = property(itemgetter(2))  # type: ignore[assignment]

    @property
    def R(self) -> Array:
        return np.frombuffer(self[3], count=9).reshape(3, 3)

    @property
    def omega(self) -> Array:
        return np.frombuffer(self[3], count=3, offset=72)

    @property
    def omega_err(self) -> Array:
        return np.frombuffer(self[3], count=3, offset=96)

    def floats(self) -> tuple[Mat9, Vec3]:
        """``R`` as a row-major 9-tuple and ``omega`` as a 3-tuple of floats, unpacked from the kept bytes
        (the host's control tick and its record compute on floats)."""
        r0, r1, r2, r3, r4, r5, r6, r7, r8, wx, wy, wz = _unpack_twelve(self[3])
        return (r0, r1, r2, r3, r4, r5, r6, r7, r8), (wx, wy, wz)

    def __repr__(self) -> str:
        return (
            f"Estimate(t={self.t!r}, R={self.R.tolist()!r}, omega={self.omega.tolist()!r}, "
            f"omega_err={self.omega_err.tolist()!r}, flags={self.flags!r}, iterations={self.iterations!r})"
        )


@dataclass(frozen=True)
class EstimateBatch:
    """Outputs for N steps: ``t`` (N,), ``R`` (N, 3, 3), ``omega`` (N, 3) Ω̂ rad/s, ``omega_err`` (N, 3),
    ``flags`` (N,) :class:`StepFlag` bits (the merger's and the estimator's), ``iterations`` (N,)."""

    t: Array
    R: Array
    omega: Array
    omega_err: Array
    flags: NDArray[np.int64]
    iterations: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @functools.cached_property
    def quat(self) -> Array:
        """Attitude as unit quaternions ``[w, x, y, z]`` (N, 4), body → inertial (computed once)."""
        return quats_of(self.R)


# --------------------------------------------------------------------------- the estimator
class VariationalEstimator:
    """The paper's estimator, one sample at a time (:meth:`update`) or over merged steps
    (:meth:`update_batch`); both run the same compiled step and give identical numbers.

    ``R0`` (3, 3) is the initial attitude estimate (body → inertial; default identity — see
    :func:`~hil.estimation.params.wahba` to start from the first measurement,
    :func:`~hil.estimation.params.paper_initial_attitude` for the paper's 127° error);
    ``omega_err0`` (3,) rad/s the initial rate-estimate error ω0; ``bias0`` (3,) rad/s the initial gyro
    bias estimate b̂0 (e.g. measured over a still window), which ``params.bias_gain`` lets the estimator
    correct online.

    The numbers live in the two arrays the kernels of :mod:`hil.estimation.variational` take (parameters,
    and the state with its counters; layouts there): :attr:`arrays` hands them to a compiled caller (the
    attitude filter's chain steps this estimator inside its own kernel).
    """

    def __init__(
        self,
        params: EstimatorParams | None = None,
        R0: ArrayLike | None = None,
        omega_err0: ArrayLike = (0.0, 0.0, 0.0),
        bias0: ArrayLike = (0.0, 0.0, 0.0),
    ) -> None:
        self.params = params or EstimatorParams()
        self._ep = k.pack_params(self.params)
        self._es = np.zeros(k.S_SIZE)  # changed in place only: the views and the kernel below keep it
        self._head = self._es[:ESTIMATE_SIZE]  # what an Estimate copies
        self._raise = self.params.on_newton_failure == "raise"
        self._update: Callable[..., int] | None = None  # k.update's machine code, bound at the first update
        self.reset(R0, omega_err0, bias0)

    def reset(
        self,
        R0: ArrayLike | None = None,
        omega_err0: ArrayLike = (0.0, 0.0, 0.0),
        bias0: ArrayLike = (0.0, 0.0, 0.0),
    ) -> None:
        """Start over from ``R0`` (default identity; projected onto SO(3)), ``omega_err0`` and ``bias0``;
        counters restart from zero."""
        r = np.eye(3) if R0 is None else so3.project(np.asarray(R0, dtype=float).reshape(3, 3))
        w = as_vec3(omega_err0)
        if w is None:
            raise ConfigError(f"must be a finite 3-vector, got {omega_err0!r}", "omega_err0")
        b = as_vec3(bias0)
        if b is None:
            raise ConfigError(f"must be a finite 3-vector, got {bias0!r}", "bias0")
        es = self._es
        es[:] = 0.0
        es[k.S_R : k.S_R + 9] = r.reshape(-1)
        es[k.S_OMEGA : k.S_OMEGA + 3] = w
        es[k.S_BIAS : k.S_BIAS + 3] = b
        es[k.S_BIAS_TRUST] = es[k.S_MAG_WEIGHT] = 1.0
        es[k.S_RATE : k.S_RATE + 3] = -np.asarray(w) - np.asarray(b)

    @property
    def arrays(self) -> tuple[Array, Array]:
        """``(parameters, state)``: the arrays themselves (not copies), for compiled callers."""
        return self._ep, self._es

    @property
    def head(self) -> Array:
        """The first :data:`ESTIMATE_SIZE` floats of the state (a view, not a copy): what an
        :class:`Estimate` of the current step holds, for :func:`estimate`."""
        return self._head

    # ----------------------------------------------------------------- snapshot / restore
    @property
    def state(self) -> EstimatorState:
        es = self._es
        return EstimatorState(
            float(es[k.S_T]),
            es[k.S_R : k.S_R + 9].reshape(3, 3).copy(),
            es[k.S_OMEGA : k.S_OMEGA + 3].copy(),
            es[k.S_GYR : k.S_GYR + 3].copy(),
            es[k.S_TORQUE : k.S_TORQUE + 3].copy(),
            bool(es[k.S_STARTED]),
            es[k.S_BIAS : k.S_BIAS + 3].copy(),
        )

    def restore(self, state: EstimatorState) -> None:
        """Continue from a snapshot taken with :attr:`state` (counters are kept)."""
        es = self._es
        es[k.S_T] = float(state.t)
        es[k.S_R : k.S_R + 9] = np.asarray(state.R, dtype=float).reshape(-1)
        es[k.S_OMEGA : k.S_OMEGA + 3] = np.asarray(state.omega_err, dtype=float).reshape(3)
        es[k.S_GYR : k.S_GYR + 3] = np.asarray(state.gyr, dtype=float).reshape(3)
        es[k.S_TORQUE : k.S_TORQUE + 3] = np.asarray(state.torque, dtype=float).reshape(3)
        es[k.S_STARTED] = 1.0 if state.started else 0.0
        es[k.S_BIAS : k.S_BIAS + 3] = np.asarray(state.bias, dtype=float).reshape(3)
        es[k.S_RATE : k.S_RATE + 3] = (
            es[k.S_GYR : k.S_GYR + 3] - es[k.S_BIAS : k.S_BIAS + 3] - es[k.S_OMEGA : k.S_OMEGA + 3]
        )

    @property
    def stats(self) -> EstimatorStats:
        c = [int(x) for x in self._es[k.S_COUNTS : k.S_COUNTS + k.C_SIZE].tolist()]
        return EstimatorStats(
            steps=c[k.C_STEPS],
            newton_failures=c[k.C_NEWTON_FAILURES],
            newton_updates=c[k.C_NEWTON_UPDATES],
            max_newton_updates=c[k.C_MAX_NEWTON_UPDATES],
            substeps=c[k.C_SUBSTEPS],
            degenerate=c[k.C_DEGENERATE],
            no_direction=c[k.C_NO_DIRECTION],
            gyro_missing=c[k.C_GYRO_MISSING],
        )

    @property
    def R(self) -> Array:
        """Current attitude estimate (3, 3), body → inertial."""
        return self._es[k.S_R : k.S_R + 9].reshape(3, 3).copy()

    @property
    def omega(self) -> Array:
        """Current body rate estimate Ω̂ = Ω^m − b̂ − ω (3,), rad/s."""
        return self._es[k.S_RATE : k.S_RATE + 3].copy()

    @property
    def bias(self) -> Array:
        """Current gyro bias estimate b̂ (3,), rad/s."""
        return self._es[k.S_BIAS : k.S_BIAS + 3].copy()

    # ----------------------------------------------------------------- stepping
    def update(
        self,
        dt: float,
        gyr: ArrayLike | None,
        acc: ArrayLike | None = None,
        mag: ArrayLike | None = None,
    ) -> Estimate:
        """Take one sample: ``dt`` s since the previous one (ignored on the first call, which only
        initialises), ``gyr`` (3,) rad/s, ``acc`` (3,) m/s² (any unit: only its direction is used), ``mag``
        (3,) (direction only), all body frame. None or non-finite means 'not usable' (see
        :mod:`hil.estimation.variational`).
        Returns the estimate at this sample."""
        try:  # lists or tuples of three: the compiled call converts their items to floats itself
            if not (
                isinstance(gyr, _SEQUENCES) and isinstance(acc, _SEQUENCES) and isinstance(mag, _SEQUENCES)
            ):
                raise TypeError
            gx, gy, gz = gyr
            ax, ay, az = acc
            mx, my, mz = mag
        except (TypeError, ValueError):  # None, arrays, a wrong length: the checked way
            gx, gy, gz = xyz(gyr)
            ax, ay, az = xyz(acc)
            mx, my, mz = xyz(mag)
        es = self._es
        snapshot = es.copy() if self._raise else None
        update = self._update
        if update is None:  # not at construction: a filter's estimator, or a batch's, never needs it
            update = self._update = jit.direct(k.update, self._ep, es, *([0.0] * 10))
        try:
            code = update(self._ep, es, dt, gx, gy, gz, ax, ay, az, mx, my, mz)
        except TypeError:  # an item that is not a number
            raise TypeError(
                f"update: dt, gyr, acc and mag must be numbers, got {dt!r}, {gyr!r}, {acc!r}, {mag!r}"
            ) from None
        if code < 0:
            raise ValueError(
                f"update: dt must be a positive number of seconds, at most {self.longest_step_s:.6g} "
                f"({MAX_SUBSTEPS} sub-steps of max_step_s), got {dt!r}"
            )
        if snapshot is not None and code & NEWTON_FAILED:
            self._fail(snapshot, 0, dt)
        return estimate(es.item(_S_T), self._head, code)

    def update_batch(self, steps: MergedSteps) -> EstimateBatch:
        """Run over merged steps (``steps.t`` strictly increasing), continuing from the current state.

        Times are on the caller's clock: an estimator that has not started adopts ``steps.t[0]`` as its
        time; one that has steps from its current time (``state.t``) to ``steps.t[0]`` first.

        The merger's flags are carried into the output; a step whose sensor is flagged stale is fed to the
        filter as 'not usable'. Same numbers as calling :meth:`update` step by step (one compiled loop).
        """
        n = len(steps)
        t = np.ascontiguousarray(steps.t, dtype=float)
        last = float(self._es[k.S_T]) if self._es[k.S_STARTED] else None
        check_times(t, last, self.longest_step_s, "update_batch")
        out = EstimateBatch(
            t.copy(),
            np.empty((n, 3, 3)),
            np.empty((n, 3)),
            np.empty((n, 3)),
            np.empty(n, np.int64),
            np.empty(n, np.int64),
        )
        es = self._es
        snapshot = es.copy() if self._raise else None
        done = k.run(
            self._ep,
            es,
            t,
            _ints(steps.flags),
            _rows(steps.gyr),
            _rows(steps.acc),
            _rows(steps.mag),
            out.R,
            out.omega,
            out.omega_err,
            out.flags,
            out.iterations,
        )
        if snapshot is not None and done and out.flags[done - 1] & NEWTON_FAILED:
            i = done - 1
            self._fail(snapshot, i, float(t[i] - (t[i - 1] if i else snapshot[k.S_T])))
        if done < n:  # a step the kernel refused, which check_times lets through: never rows unfilled
            raise ValueError(f"update_batch: step {done} at {t[done]!r} s was refused")
        return out

    @property
    def longest_step_s(self) -> float:
        """s: the longest step the estimator takes (:data:`~hil.estimation.slots.MAX_SUBSTEPS` sub-steps
        of ``max_step_s``); a longer one is a far timestamp, refused."""
        return self.params.max_step_s * MAX_SUBSTEPS

    def _fail(self, snapshot: Array, index: int, h: float) -> None:
        """Undo the call (the estimator is as it was before it) and raise the Newton failure."""
        w = self._es[k.S_OMEGA : k.S_OMEGA + 3].tolist()
        self._es[:] = snapshot
        p = self.params
        raise ConvergenceError(
            f"estimator step {index} (h = {h:g} s): Newton–Raphson did not reach "
            f"{p.newton_tol:g} rad/s in {p.newton_max_iter} updates (ω = {w})"
        )


def xyz(v: ArrayLike | None) -> tuple[float, float, float]:
    """A 3-vector as three floats for a kernel, NaNs for None (a kernel reads non-finite as 'not
    usable'). Tuples and lists of three take a fast path; anything else goes through :func:`as_vec3`
    (ValueError for a wrong shape)."""
    if v is None:
        return _NAN3
    if type(v) is tuple or type(v) is list:
        if len(v) == 3:
            x, y, z = v
            return float(x), float(y), float(z)
    a = as_vec3(v)
    return _NAN3 if a is None else a


def estimate(t: float, head: Array, code: int, flags: int = 0) -> Estimate:
    """The :class:`Estimate` at ``t`` after a step that returned ``code`` (``flags`` added), from ``head``,
    the first :data:`ESTIMATE_SIZE` floats of the state (a view kept by the caller: slicing it anew would
    cost a tenth of a sample's budget). The memoised flag is looked up inline, for the same reason."""
    bits = (code & _FLAG_BITS) | flags
    f = _FLAGS.get(bits)
    if f is None:
        f = flag(bits)
    return _new_tuple(Estimate, (t, f, code >> _ITER_SHIFT, head.tobytes()))


def flag(bits: int) -> StepFlag:
    """``StepFlag(bits)``, memoised (building an IntFlag costs ~0.3 µs; a step's budget is a few µs)."""
    f = _FLAGS.get(bits)
    if f is None:
        f = _FLAGS[bits] = StepFlag(bits)
    return f


def check_times(t: Array, last: float | None, longest_s: float, where: str) -> None:
    """Step times ``t`` (N,) s must increase strictly, start after ``last`` (the time of the step before
    them; None: none), and be at most ``longest_s`` apart (:attr:`VariationalEstimator.longest_step_s`):
    else a ValueError naming the first step that is not."""
    if not len(t):
        return
    steps = np.diff(t) if last is None else np.diff(t, prepend=last)
    first = 1 if last is None else 0  # the index in t of steps[0]'s end
    bad = np.flatnonzero(~(steps > 0))
    if bad.size:
        i = int(bad[0]) + first
        if i == 0:
            raise ValueError(f"{where}: first step time {t[0]!r} is not after the last one, {last!r}")
        raise ValueError(f"{where}: step times must increase strictly (step {i}: {t[i]!r})")
    far = np.flatnonzero(steps > longest_s)
    if far.size:
        i = int(far[0]) + first
        raise ValueError(
            f"{where}: step {i} at {t[i]!r} s is {steps[i - first]:.6g} s after the one before it, "
            f"longer than the estimator takes ({longest_s:.6g} s, {MAX_SUBSTEPS} sub-steps of max_step_s): "
            "a far timestamp, not a gap in a stream"
        )


def _rows(a: Array) -> Array:
    return np.ascontiguousarray(a, dtype=float).reshape(-1, 3)


def _ints(a: NDArray[np.int64]) -> NDArray[np.int64]:
    return np.ascontiguousarray(a, dtype=np.int64).reshape(-1)


def _concat(parts: list[EstimateBatch]) -> EstimateBatch:
    fields = ("t", "R", "omega", "omega_err", "flags", "iterations")
    return EstimateBatch(*(np.concatenate([getattr(p, f) for p in parts]) for f in fields))
