"""The ``vqf`` estimator kind: a thin adapter over VQF (Laidig & Seel, "VQF: Highly accurate IMU orientation
estimation with bias estimation and magnetic disturbance rejection", Information Fusion 2023), from the
optional ``vqf`` package (``pip install vqf``; the project's ``bench`` and ``test`` extras install it).
The second implementation of :class:`~hil.estimation.interface.Estimator`: it shows what a user's own
filter needs, and flies and replays through ``hil run --estimator vqf`` and ``hil replay --estimator vqf``.

What the adapter does, and only that:

- VQF's gains are set for a fixed sample period: the site's ``sample_period_s`` (the merged steps' nominal
  period, the fastest sensor's), and it has no per-step time. A merged step's own ``h`` is integrated as
  the whole number of nominal periods nearest to it (:func:`gyro_updates`): a step within half a period of
  the nominal one (phone jitter) is one update, as VQF is meant to be fed; a longer one — a gap shorter than
  a replay's ``max_gap_s``, a gyroscope whose rate dropped part-way — is sub-stepped as the variational
  estimator's is (:mod:`hil.estimation.reference`): that many updates, the gyroscope interpolated from the
  step before's reading to this one's, the step flagged ``SUBSTEPPED``. Before, each such step turned the
  attitude through one period (a 0.8 s gap at 200 Hz integrated as 5 ms), silently. A step of more than
  :data:`~hil.estimation.slots.MAX_SUBSTEPS` periods is refused (ValueError naming it), as the variational
  estimator's is.
- A sensor that is not usable in a step (None live, a stale flag in batch) is not fed: a stale gyroscope
  leaves the orientation where it was, a stale accelerometer or magnetometer leaves out its correction.
  A site without a magnetometer (6-axis) never feeds it, and takes VQF's 6D quaternion (heading where
  it starts).
- VQF's 9D quaternion is sensor → ENU with y toward *magnetic* north; the adapter turns it by the site's
  declination to true north, as every estimate here is.
- ``Ω̂ = Ω^m − b̂`` (VQF's bias estimate); ``omega_err`` is zero and ``iterations`` 0 (VQF takes nothing
  else off the gyroscope, and solves nothing iteratively). VQF's rest and magnetic disturbance detections
  become :attr:`~hil.estimation.sensors.StepFlag.REST` and ``MAG_DISTURBED``.
- The initial attitude is VQF's own (from its first accelerometer and magnetometer samples): a site's
  ``init`` is not used; its ``gyro_bias`` is VQF's initial bias estimate.

Pure math, no I/O; VQF is imported when an estimator is checked or built, so the project needs it only
when it is chosen."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.estimation.estimator import Estimate, EstimateBatch, flag
from hil.estimation.interface import Site
from hil.estimation.sensors import MergedStep, MergedSteps, as_vec3
from hil.estimation.slots import (
    ACC_STALE,
    GYR_STALE,
    MAG_DISTURBED,
    MAG_STALE,
    MAX_SUBSTEPS,
    REST,
    SUBSTEPPED,
)
from protocol.errors import ConfigError

Array = NDArray[np.float64]

DEFAULTS: dict[str, Any] = {
    "tau_acc_s": 3.0,
    "tau_mag_s": 9.0,
    "motion_bias": True,
    "rest_bias": True,
    "mag_rejection": True,
}
"""VQF's own defaults (its ``tauAcc``, ``tauMag``, ``motionBiasEstEnabled``, ``restBiasEstEnabled``,
``magDistRejectionEnabled``)."""

_VQF_NAMES = {
    "tau_acc_s": "tauAcc",
    "tau_mag_s": "tauMag",
    "motion_bias": "motionBiasEstEnabled",
    "rest_bias": "restBiasEstEnabled",
    "mag_rejection": "magDistRejectionEnabled",
}
_MAX_TAU_S = 1000.0
_ZERO3 = np.zeros(3)


def gyro_updates(h_s: float | None, period_s: float) -> int:
    """How many of VQF's fixed-period gyroscope updates a step of ``h_s`` (s; None: the first step, no time
    before it) stands for: the whole number of ``period_s`` nearest to it, at least 1 — the attitude turned
    through the step's real time to within half a period, as an on-time step's is. ValueError beyond
    :data:`~hil.estimation.slots.MAX_SUBSTEPS` (no gap a phone's stream has: a far timestamp)."""
    if h_s is None:
        return 1
    periods = h_s / period_s
    if not periods <= MAX_SUBSTEPS:
        raise ValueError(
            f"vqf: a step of {h_s!r} s spans more than {MAX_SUBSTEPS} of its {period_s:.6g} s periods: a "
            "recording paused or a far timestamp, not sampling (split the log at the gap: hil replay "
            "--max-gap)"
        )
    return max(1, round(periods))


def _vqf_class() -> Any:
    """VQF's class, or a ConfigError saying how to install it."""
    try:
        from vqf import VQF
    except ImportError:
        raise ConfigError(
            "the vqf estimator needs the vqf package: pip install vqf (or the project's bench extra)",
            "estimator vqf",
        ) from None
    return VQF


class VqfKind:
    """VQF by its settings (see the module docstring and :data:`DEFAULTS`)."""

    name = "vqf"
    keys = frozenset(DEFAULTS)

    def check(self, settings: Mapping[str, Any], where: str) -> dict[str, Any]:
        """The time constants positive and at most 1000 s, the switches true or false; ConfigError
        naming ``where.KEY``, or saying ``pip install vqf`` when it is not installed."""
        _vqf_class()
        checked = {**DEFAULTS, **settings}
        for key, value in checked.items():
            if key.endswith("_s"):
                number = not isinstance(value, bool) and isinstance(value, int | float)
                if not (number and math.isfinite(value) and 0 < value <= _MAX_TAU_S):
                    raise ConfigError(
                        f"must be a number of seconds in (0, {_MAX_TAU_S:g}], got {value!r}", f"{where}.{key}"
                    )
                checked[key] = float(value)
            elif not isinstance(value, bool):
                raise ConfigError(f"must be true or false, got {value!r}", f"{where}.{key}")
        return checked

    def build(self, settings: Mapping[str, Any], site: Site) -> VqfEstimator:
        return VqfEstimator(settings, site)

    def describe(self, settings: Mapping[str, Any]) -> str:
        shown = ", ".join(f"{key} {value}" for key, value in settings.items())
        return f"VQF (the vqf package): {shown}"


class VqfEstimator:
    """One VQF filter behind the :class:`~hil.estimation.interface.Estimator` protocol (see the module
    docstring): :meth:`step` live, :meth:`run` in batch, the same per-step code."""

    def __init__(self, settings: Mapping[str, Any], site: Site) -> None:
        vqf_class = _vqf_class()
        period = site.sample_period_s
        if not (math.isfinite(period) and period > 0):
            raise ConfigError(f"needs a positive sample period, got {period!r} s", "estimator vqf")
        params = {_VQF_NAMES[key]: value for key, value in settings.items()}
        self._vqf = vqf_class(period, **params)
        self._period_s = period
        self._magnetometer = site.magnetometer
        # body → ENU (true north) = Rz(−declination) · body → VQF's frame (y toward magnetic north)
        self._to_enu = (
            so3.exp((0.0, 0.0, -math.radians(site.declination_deg))) if site.magnetometer else np.eye(3)
        )
        self._vqf.setBiasEstimate(np.asarray(site.gyro_bias, dtype=float), -1.0)
        self._t: float | None = None
        self._last_gyr: Array | None = None  # the reading the last step fed (None: stale, or none yet)

    @property
    def gyro_bias(self) -> Array:
        """VQF's gyro bias estimate (3,), rad/s."""
        bias, _sigma = self._vqf.getBiasEstimate()
        return np.asarray(bias, dtype=float).copy()

    def set_gyro_bias(self, bias: ArrayLike) -> None:
        """Continue from ``bias`` (3,) rad/s (VQF's uncertainty unchanged)."""
        b = as_vec3(tuple(np.asarray(bias, dtype=float).reshape(-1).tolist()))
        if b is None:
            raise ConfigError(f"must be a finite 3-vector, got {bias!r}", "VqfEstimator.set_gyro_bias")
        self._vqf.setBiasEstimate(np.asarray(b, dtype=float), -1.0)

    def set_rest_learning(self, enabled: bool) -> None:
        """VQF's rest detection and bias estimation at rest on or off."""
        self._vqf.setRestBiasEstEnabled(bool(enabled))

    def step(self, s: MergedStep) -> Estimate:
        """One merged step (live path)."""
        updates = gyro_updates(self._advance(s.t), self._period_s)
        return self._update(s.t, updates, s.gyr, s.acc, s.mag, int(s.flags))

    def run(self, steps: MergedSteps, progress: Callable[[int, int], None] | None = None) -> EstimateBatch:
        """Every merged step (batch path): the same per-step code as :meth:`step`, a sensor flagged stale
        left out."""
        n = len(steps)
        t = np.asarray(steps.t, dtype=float)
        if n and not np.all(np.diff(t) > 0):
            i = int(np.flatnonzero(~(np.diff(t) > 0))[0])
            raise ValueError(f"vqf run: step times must increase strictly (step {i + 1}: {t[i + 1]!r})")
        h = np.diff(t, prepend=t[:1])  # s: each step's own length, from the one before
        first_h = self._advance(float(t[0])) if n else None
        out = EstimateBatch(
            t.copy(),
            np.empty((n, 3, 3)),
            np.empty((n, 3)),
            np.zeros((n, 3)),
            np.empty(n, np.int64),
            np.zeros(n, np.int64),
        )
        flags = np.asarray(steps.flags, dtype=np.int64)
        for i in range(n):
            bits = int(flags[i])
            gyr = None if bits & GYR_STALE else steps.gyr[i]
            acc = None if bits & ACC_STALE else steps.acc[i]
            mag = None if bits & MAG_STALE else steps.mag[i]
            updates = gyro_updates(float(h[i]) if i else first_h, self._period_s)
            est = self._update(float(t[i]), updates, gyr, acc, mag, bits)
            out.R[i], out.omega[i], out.flags[i] = est.R, est.omega, int(est.flags)
            if progress is not None and (i + 1) % 10_000 == 0:
                progress(i + 1, n)
        self._t = float(t[-1]) if n else self._t
        if progress is not None:
            progress(n, n)
        return out

    def _advance(self, t: float) -> float | None:
        """The step's length (s) since the last one (None for the first); its time must come after the
        last one (ValueError), as for every estimator."""
        last = self._t
        if last is not None and not t > last:
            raise ValueError(f"vqf step at t = {t!r} s is not after the last one, {last!r} s")
        self._t = t
        return None if last is None else t - last

    def _update(
        self,
        t: float,
        updates: int,
        gyr: ArrayLike | None,
        acc: ArrayLike | None,
        mag: ArrayLike | None,
        bits: int,
    ) -> Estimate:
        """Feed VQF the usable readings of one step — the gyroscope's ``updates`` times
        (:func:`gyro_updates`: the step's length in nominal periods) — and read its estimate back."""
        vqf = self._vqf
        g = None if gyr is None else np.ascontiguousarray(gyr, dtype=float)
        if g is not None:
            start = g if self._last_gyr is None else self._last_gyr
            for j in range(1, updates):  # a long step's sub-steps: the rate interpolated towards this one's
                vqf.updateGyr(np.ascontiguousarray(start + j / updates * (g - start)))
            vqf.updateGyr(g)
            if updates > 1:
                bits |= SUBSTEPPED
        self._last_gyr = g
        if acc is not None:
            vqf.updateAcc(np.ascontiguousarray(acc, dtype=float))
        if mag is not None and self._magnetometer:
            vqf.updateMag(np.ascontiguousarray(mag, dtype=float))
        q = vqf.getQuat9D() if self._magnetometer else vqf.getQuat6D()
        r = self._to_enu @ so3.quat_to_matrix(q)
        bias, _sigma = vqf.getBiasEstimate()
        omega = (_ZERO3 if g is None else g) - bias
        if vqf.getRestDetected():
            bits |= REST
        if self._magnetometer and vqf.getMagDistDetected():
            bits |= MAG_DISTURBED
        return Estimate(t, r, omega, _ZERO3, flag(bits), 0)


VQF_ESTIMATOR = VqfKind()
