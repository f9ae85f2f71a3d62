"""Numpy references for the attitude filter's compiled chain (:mod:`hil.estimation.chain`) and the stages
it runs besides the estimator: rest detection and the accelerometer's trust (:class:`Motion`,
:mod:`hil.estimation.motion`), magnetic disturbance handling (:class:`Magnetic`, :func:`mag_run`,
:mod:`hil.estimation.magnetic`) and the whole chain step by step (:func:`filter_run`, Wahba's attitude by
:func:`hil.estimation.params.wahba`). Written from the docs' description, one step at a time with numpy;
the tests compare the kernels with them to rounding; nothing runs them at run time."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil import so3
from hil.estimation.filter import FilterConfig
from hil.estimation.magnetic import MagneticSettings
from hil.estimation.motion import MotionSettings
from hil.estimation.params import wahba
from hil.estimation.reference import Estimator, Lowpass, RunResult, measurement, strapdown_step, unit
from hil.estimation.sensors import KINDS, MergedSteps, SensorKind
from hil.estimation.slots import GYRO_LIMIT, MAG_DISTURBED, REST

Array = NDArray[np.float64]

_NAN3 = np.full(3, np.nan)


class Motion:
    """Rest detection and the accelerometer's trust (:mod:`hil.estimation.motion`)."""

    def __init__(self, s: MotionSettings) -> None:
        self.s = s
        self.gyr_lp: Array | None = None
        self.acc_lp = np.zeros(3)
        self.dg2 = self.da2 = self.rest_for = 0.0
        self.rest = False
        self.calm = self.cut_scale = 1.0

    def step(self, h: float, gyr: Array, bias: Array, acc: Array) -> bool:
        s = self.s
        g_ok, a_ok = bool(np.all(np.isfinite(gyr))), bool(np.all(np.isfinite(acc)))
        if self.gyr_lp is None:
            if g_ok and a_ok:
                self.gyr_lp, self.acc_lp = gyr.copy(), acc.copy()
            return False
        k = min(1.0, h / s.tau_s)
        if g_ok:
            d = gyr - self.gyr_lp
            self.dg2 += k * (float(d @ d) - self.dg2)
            self.gyr_lp = self.gyr_lp + k * d
        if a_ok:
            d = acc - self.acc_lp
            self.da2 += k * (float(d @ d) - self.da2)
            self.acc_lp = self.acc_lp + k * d
        self.calm = 1.0 / (1.0 + self.da2 / s.acc_scale**2)
        self.cut_scale = s.dynamic + (s.calm - s.dynamic) * self.calm
        turning = float(np.linalg.norm(self.gyr_lp - bias)) >= s.rate_max
        if not (g_ok and a_ok) or self.dg2 >= s.rest_gyr**2 or self.da2 >= s.rest_acc**2 or turning:
            self.rest_for, self.rest = 0.0, False
            return False
        self.rest_for += h
        self.rest = self.rest_for >= s.rest_min_s
        return self.rest


class Magnetic:
    """The magnetic disturbance handling (:mod:`hil.estimation.magnetic`): :meth:`step` gives a weight."""

    def __init__(self, s: MagneticSettings) -> None:
        self.s = s
        self.sin_tol = math.sin(math.radians(s.dip_tol_deg))
        self.started = False
        self.has_dip = self.disturbed = self.has_prev = False
        self.norm = self.dip = 0.0
        self.ref = self.prev = self.cand = (0.0, 0.0)
        self.undisturbed_for = self.rejected_for = self.cand_for = self.confirm_for = 0.0
        self.adopted = 0
        self.confirmed = False
        self.since = 0.0

    def _full(self) -> float:
        return 1.0 + (self.s.boost - 1.0) * math.exp(-self.since / self.s.boost_s)

    def _within(self, ref: tuple[float, float]) -> bool:
        if abs(self.norm / ref[0] - 1.0) > self.s.norm_tol:
            return False
        return not self.has_dip or abs(self.dip - ref[1]) <= self.sin_tol

    def step(self, h: float, rate: float, up: Array, mag: Array) -> float:
        s = self.s
        n = float(np.linalg.norm(mag))
        if not (math.isfinite(n) and n > 0.0):
            return 0.0
        nu = float(np.linalg.norm(up))
        has_dip = math.isfinite(nu) and nu > 0.0
        dip = -float(up @ mag) / (nu * n) if has_dip else 0.0
        if not self.started:
            self.started, self.norm, self.dip, self.has_dip = True, n, dip, has_dip
            self.ref = self.cand = (n, dip)
            self.rejected_for = s.max_rejection_s
            return self._full()
        self.since += h
        k = min(1.0, h / s.current_tau_s)
        self.norm += k * (n - self.norm)
        if has_dip:
            if not self.has_dip:
                self.has_dip, self.dip = True, dip
                self.ref, self.cand = (self.ref[0], dip), (self.cand[0], dip)
            self.dip += k * (dip - self.dip)
        if self._within(self.ref):
            self.undisturbed_for += h
            if rate >= s.min_rate:
                self.confirm_for += h
                self.confirmed = self.confirmed or self.confirm_for >= s.first_steady_s
        elif self.has_prev and self._within(self.prev):
            self.ref, self.prev = self.prev, self.ref
            self.undisturbed_for += h
        else:
            self.undisturbed_for, self.disturbed = 0.0, True
        if self.disturbed and self.undisturbed_for >= s.min_undisturbed_s:
            self.disturbed = False
        kr = min(1.0, h / s.tau_s)
        if self._within(self.cand):
            if rate >= s.min_rate:
                self.cand_for += h
            self.cand = (
                self.cand[0] + kr * (self.norm - self.cand[0]),
                self.cand[1] + kr * (self.dip - self.cand[1]),
            )
        else:
            self.cand, self.cand_for = (self.norm, self.dip), 0.0
        if not self.disturbed:
            self.ref = (
                self.ref[0] + kr * (self.norm - self.ref[0]),
                self.ref[1] + kr * (self.dip - self.ref[1]),
            )
            self.rejected_for = max(0.0, self.rejected_for - s.recovery * h)
            return self._full()
        steady = s.steady_s if self.confirmed else s.first_steady_s
        if self.cand_for >= steady and s.field_min <= self.cand[0] <= s.field_max:
            self.has_prev, self.prev, self.ref, self.confirmed = self.confirmed, self.ref, self.cand, True
            self.disturbed, self.undisturbed_for = False, s.min_undisturbed_s
            self.adopted += 1
            self.since = 0.0
            return self._full()
        if self.rejected_for < s.max_rejection_s:
            self.rejected_for += h
            return 0.0
        return s.late_weight if s.field_min <= self.norm <= s.field_max else 0.0


def mag_run(settings: MagneticSettings, h: Array, rate: Array, up: Array, mag: Array) -> Array:
    """The weights :class:`Magnetic` gives N samples."""
    m = Magnetic(settings)
    return np.array([m.step(float(h[i]), float(rate[i]), up[i], mag[i]) for i in range(len(h))])


# --------------------------------------------------------------------------- the chain
def _tilt(e1: Array, acc: Array) -> Array:
    """The shortest rotation taking the unit ``acc`` to ``e1`` (body → inertial)."""
    u = acc / np.linalg.norm(acc)
    k = np.cross(u, e1)
    s, c = float(np.linalg.norm(k)), float(u @ e1)
    if s < 1e-12:
        if c > 0.0:
            return np.eye(3)
        perp = np.array([0.0, -u[2], u[1]]) if abs(u[0]) < 0.9 else np.array([-u[2], 0.0, u[0]])
        return so3.exp(math.pi * perp / np.linalg.norm(perp))
    return so3.exp(math.atan2(s, c) * k / s)


def filter_run(config: FilterConfig, steps: MergedSteps) -> RunResult:
    """The attitude filter (``config``: a :class:`hil.estimation.filter.FilterConfig`) over ``steps``
    from a fresh start, one step at a time: the gyro less b̂, the pre-filter (strapdown frame, the
    accelerometer's cut-off scaled by its trust), rest and the bias at rest, the vertical (the estimate's,
    or the accelerometer's before a measured attitude), the magnetic handling's weight, the field's
    horizontal part, the measured restart (Wahba's, or gravity's alone without a field; after Wahba's,
    for ``settle_s`` again at every step, from the readings' means in the strapdown frame), the
    estimator.
    Flags include the merger's, MAG_DISTURBED and REST."""
    p = config.params
    gyr_in, acc_in, mag_in = (np.where(steps.valid(k)[:, None], steps.value(k), np.nan) for k in KINDS)
    usable = np.all(np.abs(gyr_in) <= GYRO_LIMIT, axis=1)  # a rate no sensor reads: NaN to every stage
    gyr_in = np.where(usable[:, None], gyr_in, np.nan)
    cut = config.prefilter_rad_s
    strap = config.prefilter_frame == "strapdown"
    lp = {kind: Lowpass() for kind in KINDS}
    motion = Motion(config.motion) if config.motion is not None else None
    magnetic = Magnetic(config.mag_gate) if config.mag_gate is not None else None
    measured = isinstance(config.init, str) and config.init == "measured"
    r0 = np.eye(3) if isinstance(config.init, str) else np.asarray(config.init, dtype=float)
    est = Estimator(p, r0, np.array(config.omega_err0, dtype=float), np.array(config.gyro_bias, dtype=float))
    awaiting = "both" if measured else "none"
    settle_end = -math.inf  # settling after the measured restart until then (s)
    sums = (np.zeros(3), np.zeros(3))  # Σ R_g a, Σ R_g m over the settling
    rg, g_prev = np.eye(3), np.zeros(3)
    n = len(steps)
    out = RunResult.empty(n)
    for i in range(n):
        h = float(steps.t[i] - steps.t[i - 1]) if i else 0.0
        b = est.b.copy()
        g = gyr_in[i] - b
        acc = acc_in[i].copy()
        mag = _NAN3.copy() if config.magnetometer == "none" else mag_in[i].copy()
        g_use = g if np.all(np.isfinite(g)) else np.zeros(3)
        if strap and i:
            rg = rg @ strapdown_step(h, g_prev, g_use, p.gyro_delay_s)
            rg = rg @ (1.5 * np.eye(3) - 0.5 * rg.T @ rg)
        g_prev = g_use
        signals = {SensorKind.GYR: g, SensorKind.ACC: acc, SensorKind.MAG: mag}
        for kind in KINDS:
            c = cut.get(kind)
            if c is None:
                continue
            c = c * (motion.cut_scale if motion is not None and kind is SensorKind.ACC else 1.0)
            v = signals[kind]
            if strap and kind is not SensorKind.GYR and np.all(np.isfinite(v)):
                signals[kind] = rg.T @ lp[kind](h, rg @ v, c)
            elif strap and kind is not SensorKind.GYR and np.all(np.isfinite(g)):
                signals[kind] = lp[kind].hold()  # R_g carries the state through the drop-out
            else:
                signals[kind] = lp[kind](h, v, c)
        g, acc, mag = signals[SensorKind.GYR], signals[SensorKind.ACC], signals[SensorKind.MAG]
        flags, trust = 0, 1.0
        if motion is not None:
            rest = motion.step(h, gyr_in[i], b, rg @ acc_in[i])
            trust = motion.calm
            if rest:
                flags |= REST
                k = min(1.0, h * config.motion.rest_gain)  # type: ignore[union-attr]
                est.b = np.clip(est.b + k * (motion.gyr_lp - est.b), -p.bias_max, p.bias_max)  # type: ignore[operator]
        unit_acc = unit(acc)
        up = est.r.T @ p.E[:, 0] if awaiting == "none" else (_NAN3 if unit_acc is None else unit_acc)
        weight = 1.0
        if magnetic is not None and np.all(np.isfinite(mag)):
            weight = magnetic.step(h, float(np.linalg.norm(g)), up, mag)
            if weight < 1.0:
                flags |= MAG_DISTURBED
            if weight == 0.0:
                mag = _NAN3.copy()
        gated = mag.copy()  # the field as the magnetic handling passed it
        if config.magnetometer == "horizontal":
            mag = mag - float(mag @ up) * up
        if awaiting == "none" and steps.t[i] < settle_end:  # settling: from the means since the restart
            sums = _settle_sum(sums, rg, acc_in[i], gated)
            a_mean, m_mean = rg.T @ sums[0], rg.T @ sums[1]
            if config.magnetometer == "horizontal" and 0.0 < float(a_mean @ a_mean) < math.inf:
                m_mean = m_mean - float(m_mean @ a_mean) / float(a_mean @ a_mean) * a_mean
            if measurement(p, a_mean, m_mean).used.all():
                est = _restart(est, wahba(p, a_mean, m_mean), config)
                weight = trust = 1.0
        elif awaiting != "none":
            restarted = True
            if measurement(p, acc, mag).used.all():
                awaiting = "none"
                settle_end = float(steps.t[i]) + config.settle_s
                sums = (np.zeros(3), np.zeros(3))
                if config.settle_s > 0.0:
                    sums = _settle_sum(sums, rg, acc_in[i], gated)
                est = _restart(est, wahba(p, acc, mag), config)
            elif awaiting == "both" and unit_acc is not None:
                awaiting = "none" if config.magnetometer == "none" else "field"
                est = _restart(est, _tilt(p.E[:, 0], acc), config)
            else:
                restarted = False
            if restarted:  # a restart starts the field's weight and the torque's trust over
                weight = trust = 1.0
        est_flags, iters = est.step(h, g + b, acc, mag, weight, trust)
        out.record(i, est, int(steps.flags[i]) | flags | est_flags, iters)
    out.counters = est.counters
    return out


def _settle_sum(sums: tuple[Array, Array], rg: Array, acc: Array, mag: Array) -> tuple[Array, Array]:
    """The settling's sums with ``acc`` and ``mag`` (each left out unless finite) added in the strapdown
    frame ``rg``."""
    sa, sm = sums
    if np.all(np.isfinite(acc)):
        sa = sa + rg @ acc
    if np.all(np.isfinite(mag)):
        sm = sm + rg @ mag
    return sa, sm


def _restart(est: Estimator, r: Array, config: FilterConfig) -> Estimator:
    """A fresh estimator at ``r`` and ω0, keeping the bias estimate."""
    return Estimator(est.p, r, np.array(config.omega_err0, dtype=float), est.b.copy())
