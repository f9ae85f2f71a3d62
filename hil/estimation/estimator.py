"""The paper's variational estimator as an object: :class:`VariationalEstimator` takes one sample at a
time (:meth:`~VariationalEstimator.update`) or a batch of merged steps
(:meth:`~VariationalEstimator.update_batch`), with its state snapshot (:class:`EstimatorState`), counters
(:class:`EstimatorStats`) and outputs (:class:`Estimate`, :class:`EstimateBatch`). Pure math, no I/O.

The scheme itself (equations, Newton solve, missing measurements, long steps) is documented and implemented
in :mod:`hil.estimation.variational`; its parameters are in :mod:`hil.estimation.params`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.estimation import variational
from hil.estimation.params import EstimatorParams
from hil.estimation.sensors import MergedSteps, SensorKind, StepFlag, as_vec3
from hil.estimation.variational import _measurement_batch, _measurement_f, _run, _Tables
from hil.so3 import Mat9, Vec3
from protocol.errors import ConfigError

Array = NDArray[np.float64]

_COUNTED = (StepFlag.NEWTON_FAILED, StepFlag.DEGENERATE, StepFlag.GYR_STALE)


@dataclass(frozen=True)
class EstimatorState:
    """A snapshot of the estimator, enough to resume it exactly (``VariationalEstimator.restore``).

    ``t`` s since the first sample; ``R`` (3, 3) body → inertial; ``omega_err`` (3,) rad/s the rate-estimate
    error ω (``Ω̂ = Ω^m − ω``); ``gyr`` (3,) rad/s the last rate measurement Ω^m[i] used; ``torque`` (3,) the
    cached ``Φ'(U⁰[i]) S_L[i]``; ``started`` whether a first sample has been taken.
    """

    t: float
    R: Array
    omega_err: Array
    gyr: Array
    torque: Array
    started: bool


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


@dataclass(frozen=True, slots=True)
class Estimate:
    """The estimator's output for one sample: ``R`` (3, 3) body → inertial (ENU), ``omega`` (3,) rad/s the
    body rate estimate Ω̂, ``omega_err`` (3,) rad/s ω, ``t`` s, ``flags``, Newton ``iterations`` taken."""

    t: float
    R: Array
    omega: Array
    omega_err: Array
    flags: StepFlag
    iterations: int


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

    @property
    def quat(self) -> Array:
        """Attitude as unit quaternions ``[w, x, y, z]`` (N, 4), body → inertial."""
        return so3.matrix_to_quat(self.R)


# --------------------------------------------------------------------------- the estimator
class VariationalEstimator:
    """The paper's estimator, one sample at a time (:meth:`update`) or over merged steps
    (:meth:`update_batch`); both run the same kernel and give identical numbers.

    ``R0`` (3, 3) is the initial attitude estimate (body → inertial; default identity — see
    :func:`~hil.estimation.params.wahba` to start from the first measurement,
    :func:`~hil.estimation.params.paper_initial_attitude` for the paper's 127° error);
    ``omega_err0`` (3,) rad/s the initial rate-estimate error ω0.
    """

    def __init__(
        self,
        params: EstimatorParams | None = None,
        R0: ArrayLike | None = None,
        omega_err0: ArrayLike = (0.0, 0.0, 0.0),
    ) -> None:
        self.params = params or EstimatorParams()
        self._tb = _Tables(self.params)
        self.reset(R0, omega_err0)

    def reset(self, R0: ArrayLike | None = None, omega_err0: ArrayLike = (0.0, 0.0, 0.0)) -> None:
        """Start over from ``R0`` (default identity; projected onto SO(3)) and ``omega_err0``."""
        r = np.eye(3) if R0 is None else so3.project(np.asarray(R0, dtype=float).reshape(3, 3))
        self._r: Mat9 = tuple(r.reshape(-1).tolist())  # type: ignore[assignment]
        w = as_vec3(omega_err0)
        if w is None:
            raise ConfigError(f"must be a finite 3-vector, got {omega_err0!r}", "omega_err0")
        self._w: Vec3 = w
        self._g: Vec3 = (0.0, 0.0, 0.0)
        self._tau: Vec3 = (0.0, 0.0, 0.0)
        self._t = 0.0
        self._started = False
        self._flag_steps = self._no_direction = self._substeps = self._newton_updates = self._max_updates = 0
        self._flag_counts = dict.fromkeys(_COUNTED, 0)

    # ----------------------------------------------------------------- snapshot / restore
    @property
    def state(self) -> EstimatorState:
        return EstimatorState(
            self._t,
            np.array(self._r).reshape(3, 3),
            np.array(self._w),
            np.array(self._g),
            np.array(self._tau),
            self._started,
        )

    def restore(self, state: EstimatorState) -> None:
        """Continue from a snapshot taken with :attr:`state` (counters are kept)."""
        self._t = float(state.t)
        self._r = tuple(np.asarray(state.R, dtype=float).reshape(-1).tolist())  # type: ignore[assignment]
        self._w = tuple(np.asarray(state.omega_err, dtype=float).tolist())  # type: ignore[assignment]
        self._g = tuple(np.asarray(state.gyr, dtype=float).tolist())  # type: ignore[assignment]
        self._tau = tuple(np.asarray(state.torque, dtype=float).tolist())  # type: ignore[assignment]
        self._started = bool(state.started)

    @property
    def stats(self) -> EstimatorStats:
        fc = self._flag_counts
        return EstimatorStats(
            steps=self._flag_steps,
            newton_failures=fc[StepFlag.NEWTON_FAILED],
            newton_updates=self._newton_updates,
            max_newton_updates=self._max_updates,
            substeps=self._substeps,
            degenerate=fc[StepFlag.DEGENERATE],
            no_direction=self._no_direction,
            gyro_missing=fc[StepFlag.GYR_STALE],
        )

    @property
    def R(self) -> Array:
        """Current attitude estimate (3, 3), body → inertial."""
        return np.array(self._r).reshape(3, 3)

    @property
    def omega(self) -> Array:
        """Current body rate estimate Ω̂ = Ω^m − ω (3,), rad/s."""
        return np.subtract(self._g, self._w)

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
        tb = self._tb
        g = as_vec3(gyr)
        flags = StepFlag.NONE
        if g is None:
            g = (0.0, 0.0, 0.0)
            flags |= StepFlag.GYR_STALE
        big_l, k, mflags = _measurement_f(tb, as_vec3(acc), as_vec3(mag))
        flags |= mflags
        if self._started:
            if not (math.isfinite(dt) and dt > 0.0):
                raise ValueError(f"update: dt must be a positive number of seconds, got {dt!r}")
            f_out: list[int] = []
            it_out: list[int] = []
            self._advance_all([dt], [list(g)], [big_l], [k], [], [], f_out, it_out)  # type: ignore[list-item]
            self._t += dt
            flags |= f_out[0]
            iters = it_out[0]
        else:
            iters = self._start(g, big_l, k)
        self._tally(int(flags), big_l is None)
        return Estimate(
            self._t,
            np.array(self._r).reshape(3, 3),
            np.subtract(g, self._w),
            np.array(self._w),
            flags,
            iters,
        )

    def update_batch(self, steps: MergedSteps) -> EstimateBatch:
        """Run over merged steps (``steps.t`` strictly increasing), continuing from the current state.

        Times are on the caller's clock: an estimator that has not started adopts ``steps.t[0]`` as its
        time; one that has steps from its current time (``state.t``) to ``steps.t[0]`` first.

        The merger's flags are carried into the output; a step whose sensor is flagged stale is fed to the
        filter as 'not usable'. Same numbers as calling :meth:`update` step by step (to rounding: the
        measurement terms are computed vectorised here).
        """
        tb = self._tb
        n = len(steps)
        t = steps.t
        if n and not np.all(np.diff(t) > 0):
            k = int(np.flatnonzero(~(np.diff(t) > 0))[0])
            raise ValueError(f"update_batch: step times must increase strictly (step {k + 1}: {t[k + 1]!r})")
        gyr_ok = steps.valid(SensorKind.GYR) & np.all(np.isfinite(steps.gyr), axis=1)
        acc = np.where(steps.valid(SensorKind.ACC)[:, None], steps.acc, np.nan)
        mag = np.where(steps.valid(SensorKind.MAG)[:, None], steps.mag, np.nan)
        big_ls, ks, mflags = _measurement_batch(tb, acc, mag)
        gyr = np.where(gyr_ok[:, None], steps.gyr, 0.0)
        flags = steps.flags | mflags | np.where(gyr_ok, 0, int(StepFlag.GYR_STALE))
        out_r: list[Mat9] = []
        out_w: list[Vec3] = []
        step_flags: list[int] = []
        iters: list[int] = []
        gyrs = gyr.tolist()
        first = 0
        if n and not self._started:
            self._t = float(t[0])
            self._start(tuple(gyrs[0]), big_ls[0], ks[0])  # type: ignore[arg-type]
            out_r.append(self._r)
            out_w.append(self._w)
            step_flags.append(0)
            iters.append(0)
            first = 1
        hs = np.diff(t, prepend=self._t)[first:].tolist()
        if hs and not hs[0] > 0:
            raise ValueError(
                f"update_batch: first step time {t[0]!r} is not after the estimator's {self._t!r}"
            )
        self._t = float(t[-1]) if n else self._t
        self._advance_all(hs, gyrs[first:], big_ls[first:], ks[first:], out_r, out_w, step_flags, iters)
        flags |= np.asarray(step_flags, dtype=np.int64).reshape(n)
        self._tally(flags, sum(b is None for b in big_ls))
        w_arr = np.asarray(out_w, dtype=float).reshape(n, 3)
        return EstimateBatch(
            t.copy(),
            np.asarray(out_r, dtype=float).reshape(n, 3, 3),
            gyr - w_arr,
            w_arr,
            flags,
            np.asarray(iters, dtype=np.int64).reshape(n),
        )

    def _start(self, g: Vec3, big_l: Mat9 | list[float] | None, k: float) -> int:
        """Take the first sample: it sets Ω^m[0] and the cached torque at R̂0; no step."""
        self._started = True
        self._g = g
        # called through the module so that one patch of variational._torque covers this and every step
        self._tau = variational._torque(self._tb, self._r, big_l, k)
        return 0

    def _advance_all(
        self,
        hs: list[float],
        gyrs: list[list[float]],
        big_ls: list[list[float] | None],
        ks: list[float],
        *outs: list,  # type: ignore[type-arg]
    ) -> None:
        state = (self._r, self._w, self._g, self._tau)
        state, substeps, updates, most = _run(self._tb, state, hs, gyrs, big_ls, ks, *outs)
        self._r, self._w, self._g, self._tau = state
        self._substeps += substeps
        self._newton_updates += updates
        self._max_updates = max(self._max_updates, most)

    def _tally(self, flags: NDArray[np.int64] | int, no_direction: int) -> None:
        """Count steps and the flag bits that feed :class:`EstimatorStats` (one step's int, or an array)."""
        if isinstance(flags, int):
            self._flag_steps += 1
            if flags:
                for bit in _COUNTED:
                    self._flag_counts[bit] += bool(flags & bit)
        else:
            self._flag_steps += int(flags.shape[0])
            for bit in _COUNTED:
                self._flag_counts[bit] += int(np.count_nonzero(flags & int(bit)))
        self._no_direction += int(no_direction)


def _concat(parts: list[EstimateBatch]) -> EstimateBatch:
    fields = ("t", "R", "omega", "omega_err", "flags", "iterations")
    return EstimateBatch(*(np.concatenate([getattr(p, f) for p in parts]) for f in fields))
