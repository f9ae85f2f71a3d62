"""A simulated phone: a true attitude/rate trajectory in, accelerometer, gyroscope and magnetometer samples
out, each sensor at its own rate with its own timestamp jitter, white noise and constant bias, as a
:class:`hil.scenario.phone.PhoneSpec` states them (its defaults are a Nexus 5's, with where each figure comes
from).

Frames: body = the Android sensor frame (x screen right, y screen up, z out of the screen); the world is
ENU. The accelerometer measures the specific force ``Rᵀ (g·up + a_lin)`` (gravity included, like Android's
TYPE_ACCELEROMETER); the magnetometer ``Rᵀ B``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.estimation.sensors import KINDS, SensorKind, SensorLog, SensorSample, SensorStream, Truth
from hil.jit import kernel
from hil.scenario.phone import PhoneSpec
from hil.so3.floats import log_f  # the one float log(R)
from protocol.errors import ConfigError

from .kernels import MAX_TIME_S, exp9  # the plant's exp(φ^×): one kernel for both

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Trajectory:
    """The truth: ``t`` (N,) s, ``R`` (N, 3, 3) body → ENU, ``omega`` (N, 3) body rate rad/s, ``acc_enu``
    (N, 3) linear acceleration in ENU (m/s², zero for a testbed that only rotates); ``increments`` (N−1, 3)
    the rotation vectors with ``R[i+1] = R[i] exp(increments[i])``, used to interpolate exactly."""

    t: Array
    R: Array
    omega: Array
    acc_enu: Array
    increments: Array

    @classmethod
    def from_rate(
        cls,
        rate: Callable[[float], ArrayLike],
        duration_s: float,
        R0: ArrayLike | None = None,
        dt: float = 1e-3,
        acc_enu: Callable[[float], ArrayLike] | None = None,
    ) -> Trajectory:
        """Integrate a body-rate function (rad/s) from ``R0`` with the midpoint rule on SO(3) at ``dt``."""
        n = int(round(duration_s / dt)) + 1
        t = np.arange(n, dtype=float) * dt
        omega = np.array([rate(x) for x in t], dtype=float).reshape(n, 3)
        inc = dt * np.array([rate(x + dt / 2) for x in t[:-1]], dtype=float).reshape(n - 1, 3)
        steps = so3.exp(inc)
        r = np.empty((n, 3, 3))
        r[0] = np.eye(3) if R0 is None else np.asarray(R0, dtype=float)
        for i in range(n - 1):
            r[i + 1] = r[i] @ steps[i]
        lin = np.zeros((n, 3)) if acc_enu is None else np.array([acc_enu(x) for x in t], float).reshape(n, 3)
        return cls(t, r, omega, lin, inc)

    def sample(self, times: Array) -> tuple[Array, Array, Array]:
        """``(R, omega, acc_enu)`` at ``times`` (within the trajectory): attitude by geodesic interpolation
        between grid points, rate and linear acceleration linearly."""
        times = np.asarray(times, dtype=float)
        i = np.clip(np.searchsorted(self.t, times, side="right") - 1, 0, len(self.t) - 2)
        f = ((times - self.t[i]) / (self.t[i + 1] - self.t[i]))[:, None]
        r = self.R[i] @ so3.exp(f * self.increments[i])
        omega = self.omega[i] + f * (self.omega[i + 1] - self.omega[i])
        acc = self.acc_enu[i] + f * (self.acc_enu[i + 1] - self.acc_enu[i])
        return r, omega, acc

    @property
    def truth(self) -> Truth:
        return Truth(self.t, self.R)


def paper_testbed_rate(t: float) -> Array:
    """A phone on the paper's spacecraft-simulator testbed: a smooth body rate of 0.1–0.3 rad/s."""
    return np.array([0.1 * math.sin(0.3 * t) + 0.1, 0.2 * math.cos(0.2 * t), 0.15 * math.sin(0.1 * t + 1.0)])


def simulate(traj: Trajectory, spec: PhoneSpec | None = None, seed: int | None = 0) -> SensorLog:
    """Sample the three sensors along ``traj`` (see the module docstring for the model). Returns a
    :class:`SensorLog` with the trajectory as its ground truth; the same seed gives the same log."""
    spec = spec or PhoneSpec()
    rng = np.random.default_rng(seed)
    up_force = np.array([0.0, 0.0, spec.gravity])
    b_enu = np.asarray(spec.field_enu_uT, dtype=float)
    streams = {}
    for kind in (SensorKind.GYR, SensorKind.ACC, SensorKind.MAG):
        s = spec.spec(kind)
        nominal = s.offset_s + np.arange(0.0, traj.t[-1] - s.offset_s - 4 * s.jitter_s, 1.0 / s.rate_hz)
        times = nominal + rng.normal(0.0, s.jitter_s, nominal.shape) if s.jitter_s else nominal
        times = times[(times >= traj.t[0]) & (times <= traj.t[-1])]
        r, omega, lin = traj.sample(times)
        if kind is SensorKind.GYR:
            clean = omega
        elif kind is SensorKind.ACC:
            clean = np.einsum("nji,nj->ni", r, up_force + lin)
        else:
            clean = np.einsum("nji,j->ni", r, b_enu)
        bias = rng.normal(0.0, s.bias, 3)
        streams[kind] = SensorStream(kind, times, clean + bias + rng.normal(0.0, s.noise, clean.shape))
    notes = (f"simulated phone: {spec!r}", f"seed {seed}")
    return SensorLog(streams, "simulated phone", "simulated", traj.truth, notes)


class BodyPhone:
    """A phone fixed to a simulated body (its frame = the body frame), sampled from the body's true motion as
    a simulation produces it: the emulator's world and the lockstep closed loop.

    Each sensor samples at its own rate (``spec``) from ``t0`` on, with timestamp jitter, white noise and
    a constant bias drawn once from ``seed``. Between two true states the attitude is interpolated along
    the geodesic and the rate linearly. The world is ENU on the ground: the accelerometer reads
    ``Rᵀ g·up``, the magnetometer ``Rᵀ B``.

    Two ways to sample, giving the same samples to rounding: :meth:`sample` between two states (numpy, the
    reference) and :meth:`sample_path` along many (one compiled call, :func:`_sample_path`). Both take
    their noise from one stream of standard normals drawn from the seeded generator in blocks, in the
    order ``rng.normal(0, σ, 3)`` then ``rng.normal(0, σ_t)`` per sample would draw them (bit for bit the
    same numbers), so either may follow the other."""

    def __init__(self, spec: PhoneSpec | None = None, seed: int = 0, t0: float = 0.0) -> None:
        _check_time(t0, "BodyPhone.t0")
        self.spec = spec if spec is not None else PhoneSpec.nexus5()
        self.rng = np.random.default_rng(seed)
        self.kinds = KINDS
        self.bias = {k: self.rng.normal(0.0, self.spec.spec(k).bias, 3) for k in KINDS}
        self._next = np.array([t0 + self.spec.spec(k).offset_s for k in KINDS])  # next nominal times
        self._gravity = np.array([0.0, 0.0, self.spec.gravity])
        self._field = np.asarray(self.spec.field_enu_uT, dtype=float)
        sensors = [self.spec.spec(k) for k in KINDS]
        # per sensor: rate, noise, jitter; biases; what it measures (gyro: unused)
        self._table = np.array([[s.rate_hz, s.noise, s.jitter_s] for s in sensors])
        self._bias = np.array([self.bias[k] for k in KINDS])
        self._vectors = np.array([np.zeros(3), self._gravity, self._field])
        self._normals = np.zeros(0)
        self._used = 0
        self._out = np.empty((0, 6))
        self._rng_state = self.rng.bit_generator.state
        """The generator's state as of its last draw (:meth:`_draws` keeps it), for :meth:`checkpoint`."""

    @property
    def next_t(self) -> dict[SensorKind, float]:
        """Each sensor's next nominal sample time (s)."""
        return {k: float(t) for k, t in zip(KINDS, self._next, strict=True)}

    def _draws(self, count: int) -> None:
        """At least ``count`` unused standard normals in the buffer (new ones appended, in order)."""
        left = self._normals[self._used :]
        if left.size < count:
            self._normals = np.concatenate([left, self.rng.standard_normal(max(count, _BLOCK))])
            self._used = 0
            self._rng_state = self.rng.bit_generator.state

    def _take(self, count: int) -> Array:
        self._draws(count)
        out = self._normals[self._used : self._used + count]
        self._used += count
        return out

    def sample(
        self, t0: float, R0: Array, omega0: Array, t1: float, R1: Array, omega1: Array
    ) -> list[SensorSample]:
        """The samples every sensor takes in (t0, t1], sorted by timestamp, from the true attitudes
        ``R0``, ``R1`` (3, 3) body → ENU and body rates ``omega0``, ``omega1`` (3,) rad/s at t0 and t1."""
        _check_time(t0, "BodyPhone.sample.t0")
        _check_time(t1, "BodyPhone.sample.t1")
        out: list[SensorSample] = []
        span = t1 - t0
        turn = so3.log(R0.T @ R1) if span > 0 else np.zeros(3)
        for i, k in enumerate(self.kinds):
            sensor = self.spec.spec(k)
            while self._next[i] <= t1:
                t = float(self._next[i])
                self._next[i] += 1.0 / sensor.rate_hz
                f = (t - t0) / span if span > 0 else 1.0
                if k is SensorKind.GYR:
                    clean = omega0 + f * (omega1 - omega0)
                else:
                    R = R0 @ so3.exp(f * turn)
                    clean = R.T @ (self._gravity if k is SensorKind.ACC else self._field)
                noisy = clean + self.bias[k] + (0.0 + sensor.noise * self._take(3))
                stamp = t + ((0.0 + sensor.jitter_s * float(self._take(1)[0])) if sensor.jitter_s else 0.0)
                out.append(SensorSample(stamp, k, (float(noisy[0]), float(noisy[1]), float(noisy[2]))))
        out.sort(key=lambda s: s.t_s)
        return out

    def checkpoint(self) -> tuple:
        """The sampler's state now (next sample times, noise stream), for :meth:`restore`.

        The generator's state is the one kept at its last draw, not read anew: reading it builds a dict of
        Python ints (the world checkpoints at every batch, 50 times a simulated second, where that read was
        3 % of the world's time), and only :meth:`_draws` draws from it after the biases (a caller that
        draws from :attr:`rng` itself must not checkpoint across it). ``tests/test_phone_model.py`` checks
        it against the read."""
        return self._next.copy(), self._normals, self._used, self._rng_state

    def restore(self, checkpoint: tuple) -> None:
        """Back to a :meth:`checkpoint`: the samples taken since are taken again, the same."""
        next_t, self._normals, self._used, state = checkpoint
        self.rng.bit_generator.state = self._rng_state = state
        self._next = next_t.copy()

    def sample_path(self, path: Array) -> list[SensorSample]:
        """The samples every sensor takes along ``path`` (m + 1, 13), rows ``[t, R (9, row-major, body →
        ENU), Ω (3)]`` of successive true states: what :meth:`sample` gives for each pair of consecutive
        rows in turn (each pair's samples sorted by timestamp), in one compiled call."""
        return self.sample_path_intervals(path)[0]

    def sample_path_intervals(self, path: Array) -> tuple[list[SensorSample], NDArray[np.int64]]:
        """:meth:`sample_path`, and for each sample the interval of ``path`` it was taken in (its first
        row's index; non-decreasing)."""
        path = np.ascontiguousarray(path, dtype=float)
        if path.ndim != 2 or path.shape[1] != 13:
            raise ConfigError(f"needs a path of (m + 1, 13), got {path.shape}", "BodyPhone.sample_path")
        if path.shape[0] < 2:
            return [], _NONE
        times = path[:, 0]
        _check_time(float(times[0]), "BodyPhone.sample_path (its first time)")
        _check_time(float(times[-1]), "BodyPhone.sample_path (its last time)")
        if not (times[1:] >= times[:-1]).all():  # the method: np.all's wrapper was 2 % of a world
            raise ConfigError("a path whose times run backwards", "BodyPhone.sample_path")
        end = float(path[-1, 0])
        cap = 0  # samples due by the path's end, and a margin
        for t, rate in zip(self._next.tolist(), self._table[:, 0].tolist(), strict=True):
            if t <= end:
                cap += int((end - t) * rate) + 2
        if cap == 0:  # no sensor is due: nothing to draw or sample
            return [], _NONE
        self._draws(4 * cap)
        if self._out.shape[0] < cap:
            self._out = np.empty((2 * cap, 6))
        out = self._out
        next_t = self._next.copy()  # taken over only if the sampler succeeds
        count, used = _sample_path(
            path, self._table, self._bias, self._vectors, next_t, self._normals, self._used, out
        )
        if count < 0:
            raise ConfigError(f"the sampler refused the path (status {count})", "BodyPhone.sample_path")
        self._next, self._used = next_t, used
        if count == 0:
            return [], _NONE
        rows = out[:count]
        if count > 1:
            rows = rows[np.lexsort((rows[:, 1], rows[:, 0]))]  # by interval, then stamp, as sample() sorts
        kinds = self.kinds
        samples = [SensorSample(t, kinds[int(k)], (x, y, z)) for _, t, k, x, y, z in rows.tolist()]
        return samples, rows[:, 0].astype(np.int64)


def _check_time(t: float, where: str) -> None:
    """Refuse a time (s) that is not finite or lies beyond :data:`.kernels.MAX_TIME_S`, where a sample
    period no longer moves a float64 time (ConfigError naming ``where``)."""
    if not abs(t) <= MAX_TIME_S:
        raise ConfigError(
            f"must be a finite time within ±{MAX_TIME_S:.6g} s (float64 keeps 1 µs there), got {t!r}", where
        )


_BLOCK = 4096
_NONE = np.zeros(0, np.int64)
"""Standard normals drawn at a time for the phone's noise."""


@kernel
def _sample_path(
    path: Array,
    table: Array,
    bias: Array,
    vectors: Array,
    next_t: Array,
    normals: Array,
    used: int,
    out: Array,
) -> tuple[int, int]:
    """:meth:`BodyPhone.sample` along every interval of ``path`` (rows ``[t, R (9), Ω (3)]``), unsorted:
    rows of ``out`` are ``[interval, stamp, sensor index, x, y, z]``. ``table`` (3, 3) per sensor
    rate, noise, jitter; ``bias`` (3, 3); ``vectors`` (3, 3) what each senses in ENU (gyro: unused);
    ``next_t`` (3,) each sensor's next nominal time (advanced in place); ``normals[used:]`` the noise
    stream. Returns ``(samples written, normals used)``; (-1, used) if the times run backwards, (-2, used)
    if ``out`` is full (the caller sized it from the rates)."""
    count = 0
    R0T1 = np.empty(9)
    turn = np.empty(3)
    E = np.empty(9)
    for i in range(path.shape[0] - 1):
        a, b = path[i], path[i + 1]
        t0, t1 = a[0], b[0]
        span = t1 - t0
        if span < 0.0:
            return -1, used
        if span > 0.0:
            for r in range(3):
                for c in range(3):
                    R0T1[3 * r + c] = a[1 + r] * b[1 + c] + a[4 + r] * b[4 + c] + a[7 + r] * b[7 + c]
            turn[0], turn[1], turn[2] = log_f(
                (R0T1[0], R0T1[1], R0T1[2], R0T1[3], R0T1[4], R0T1[5], R0T1[6], R0T1[7], R0T1[8])
            )
        else:
            turn[0] = turn[1] = turn[2] = 0.0
        for k in range(3):
            rate, noise, jitter = table[k, 0], table[k, 1], table[k, 2]
            while next_t[k] <= t1:
                if count == out.shape[0]:
                    return -2, used
                t = next_t[k]
                next_t[k] += 1.0 / rate
                f = (t - t0) / span if span > 0.0 else 1.0
                row = out[count]
                if k == 0:
                    for j in range(3):
                        row[3 + j] = a[10 + j] + f * (b[10 + j] - a[10 + j])
                else:
                    exp9(f * turn[0], f * turn[1], f * turn[2], E)
                    v = vectors[k]
                    for j in range(3):  # (R₀ E)ᵀ v = Eᵀ (R₀ᵀ v)
                        row[3 + j] = 0.0
                    for q in range(3):
                        w = a[1 + q] * v[0] + a[4 + q] * v[1] + a[7 + q] * v[2]
                        for j in range(3):
                            row[3 + j] += E[3 * q + j] * w
                for j in range(3):
                    row[3 + j] = row[3 + j] + bias[k, j] + (0.0 + noise * normals[used + j])
                used += 3
                if jitter != 0.0:
                    row[1] = t + (0.0 + jitter * normals[used])
                    used += 1
                else:
                    row[1] = t + 0.0
                row[0] = i
                row[2] = k
                count += 1
    return count, used
