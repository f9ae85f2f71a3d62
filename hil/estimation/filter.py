"""The attitude filter as it runs on a phone's merged steps: gyro bias removal, the pre-filter, the
magnetic gate, the magnetometer's handling (full field or horizontal part) and the measured initial
attitude around :class:`hil.estimation.estimator.VariationalEstimator` (:class:`AttitudeFilter`), set up
by :class:`FilterConfig` with the paper's or the tuned (:data:`TUNED`) settings. Pure math, no I/O."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import astuple, dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation.estimator import Estimate, EstimateBatch, VariationalEstimator, _concat
from hil.estimation.inertial import directions_from_dip
from hil.estimation.params import EstimatorParams, wahba
from hil.estimation.prefilter import PAPER_CUTOFF_RAD_S, GateSettings, MagneticGate, SignalPrefilter
from hil.estimation.sensors import KINDS, MergedStep, MergedSteps, SensorKind, StepFlag, as_vec3
from hil.so3 import Vec3
from protocol.errors import ConfigError

Array = NDArray[np.float64]


PAPER_PREFILTER: dict[SensorKind, float | None] = {k: PAPER_CUTOFF_RAD_S for k in KINDS}
"""The paper's pre-filter: every measured quantity through the 1 rad/s first-order Butterworth."""


@dataclass(frozen=True)
class FilterConfig:
    """The estimator as it runs on a phone's merged steps: what happens to the measurements first.

    ``prefilter_rad_s``: pre-filter cut-off per sensor (rad/s), None for none; ``prefilter_frame``
    ``"body"`` (the paper) or ``"strapdown"`` (see :class:`hil.estimation.prefilter.SignalPrefilter`).
    ``gyro_bias`` (3,) rad/s: subtracted from every gyro sample first (e.g. measured over a still window).
    ``magnetometer``: ``"full"`` uses the field direction as measured (the paper; E's e2 is the full field
    direction); ``"horizontal"`` uses its component perpendicular to the measured gravity direction, so that
    the magnetometer informs heading only (E's e2 must then be horizontal, e.g. magnetic north).
    ``init``: initial attitude — ``"measured"`` (Wahba's solution from the first step with both directions),
    ``"identity"``, or a (3, 3) body → inertial matrix; ``omega_err0`` (3,) rad/s the initial ω.
    ``mag_gate``: reject disturbed magnetometer samples (:class:`hil.estimation.prefilter.MagneticGate`),
    or None.
    """

    params: EstimatorParams = field(default_factory=EstimatorParams)
    prefilter_rad_s: dict[SensorKind, float | None] = field(default_factory=lambda: dict(PAPER_PREFILTER))
    prefilter_frame: Literal["body", "strapdown"] = "body"
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    magnetometer: Literal["full", "horizontal"] = "full"
    init: Literal["measured", "identity"] | ArrayLike = "measured"
    omega_err0: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_gate: GateSettings | None = None

    def __post_init__(self) -> None:
        if self.magnetometer not in ("full", "horizontal"):
            raise ConfigError(
                f"must be 'full' or 'horizontal', got {self.magnetometer!r}", "FilterConfig.magnetometer"
            )
        if self.magnetometer == "horizontal" and abs(float(self.params.E[2, 1])) > 1e-9:
            raise ConfigError(
                "a horizontal magnetometer needs a horizontal e2 (E[2, 1] = 0)", "FilterConfig.params.E"
            )
        if as_vec3(self.gyro_bias) is None:
            raise ConfigError(f"must be a finite 3-vector, got {self.gyro_bias!r}", "FilterConfig.gyro_bias")
        if isinstance(self.init, str) and self.init not in ("measured", "identity"):
            raise ConfigError(f"must be 'measured', 'identity' or a 3x3 matrix, got {self.init!r}", "init")

    @classmethod
    def paper(cls, E: ArrayLike | None = None, **overrides: object) -> FilterConfig:
        """Exactly the paper: its W, m, D, Φ(x) = x, the 1 rad/s body-frame pre-filter on all three
        signals, the full field direction; ``E`` defaults to the paper's (its site's field)."""
        params = EstimatorParams() if E is None else EstimatorParams(E=np.asarray(E, dtype=float))
        return cls(params=params, **overrides)  # type: ignore[arg-type]

    @classmethod
    def tuned(cls, declination_deg: float = 0.0, **overrides: object) -> FilterConfig:
        """The paper's estimator with the gains and measurement handling tuned on real phone/IMU logs
        (see docs/estimator.md, "Tuning"): :data:`TUNED`; E is magnetic north (or true north given the
        declination) with a horizontal magnetometer, so only the field's direction in the horizontal
        plane matters and no inclination is needed."""
        params = EstimatorParams(E=directions_from_dip(0.0, declination_deg), W=np.diag(TUNED["W_diag"]),
                                 m=TUNED["m"], D=np.diag(TUNED["D_diag"]))  # fmt: skip
        cut = {SensorKind.ACC: TUNED["acc_cutoff"], SensorKind.MAG: TUNED["mag_cutoff"], SensorKind.GYR: None}
        base = {
            "params": params,
            "prefilter_rad_s": cut,
            "prefilter_frame": "strapdown",
            "magnetometer": "horizontal",
            "mag_gate": TUNED["mag_gate"],
        }
        return cls(**{**base, **overrides})  # type: ignore[arg-type]


TUNED: dict = {
    "W_diag": (6.0, 1.0, 0.25),
    "m": 0.1,
    "D_diag": (6.0, 6.5, 7.0),
    "acc_cutoff": 0.15,
    "mag_cutoff": None,
    "mag_gate": GateSettings(norm_tol=0.2, dip_tol_deg=15.0),
}
"""Tuned settings: a two-stage grid search (``python -m bench.bench_estimator --tune``) minimising the
mean total RMSE over six real trials (three tyrex smartphone, three BROAD), then the magnetometer gate's
tolerances chosen on the same six; see docs/estimator.md."""


class AttitudeFilter:
    """Gyro bias removal, pre-filter, magnetometer handling, then the estimator, over merged steps:
    :meth:`step` live (one :class:`MergedStep`), :meth:`run` in batch (:class:`MergedSteps`); both give
    the same numbers (to rounding).

    With ``init="measured"`` the estimator (re)starts at the first step where both directions are usable,
    from Wahba's solution for that step's (pre-filtered) measurement; steps before it run from identity.
    """

    def __init__(self, config: FilterConfig | None = None) -> None:
        self.config = config or FilterConfig()
        self.prefilter = SignalPrefilter(self.config.prefilter_rad_s, self.config.prefilter_frame)
        init = self.config.init
        r0 = None if isinstance(init, str) else init
        self._awaiting_measurement = isinstance(init, str) and init == "measured"
        self.estimator = VariationalEstimator(self.config.params, r0, self.config.omega_err0)
        self._bias = self.config.gyro_bias
        gate = self.config.mag_gate
        self.gate = None if gate is None else MagneticGate(*astuple(gate))

    def set_gyro_bias(self, bias: ArrayLike) -> None:
        """Subtract ``bias`` (3,) rad/s from every later gyro sample: a bias measured while running (the
        host's still window) — the estimator's attitude would otherwise carry a steady offset from it."""
        b = as_vec3(tuple(np.asarray(bias, dtype=float).tolist()))
        if b is None:
            raise ConfigError(f"must be a finite 3-vector, got {bias!r}", "AttitudeFilter.set_gyro_bias")
        self._bias = b

    def step(self, s: MergedStep) -> Estimate:
        """One merged step (live path)."""
        g = s.gyr
        if g is not None:
            b = self._bias
            g = (g[0] - b[0], g[1] - b[1], g[2] - b[2])
        g, acc, mag = self.prefilter.step(s.h, g, s.acc, s.mag)
        gated = StepFlag.NONE
        if self.gate is not None and mag is not None:
            mag = self.gate.step(s.h, acc, mag)
            gated = StepFlag.MAG_DISTURBED if mag is None else gated
        if self.config.magnetometer == "horizontal":
            mag = _horizontal_f(acc, mag)
        if self._awaiting_measurement and _both_usable(acc, mag, self.estimator.params):
            self._awaiting_measurement = False
            self.estimator.reset(wahba(self.config.params, acc, mag), self.config.omega_err0)  # type: ignore[arg-type]
        out = self.estimator.update(s.h, g, acc, mag)
        return Estimate(s.t, out.R, out.omega, out.omega_err, out.flags | s.flags | gated, out.iterations)

    def run(
        self, steps: MergedSteps, progress: Callable[[int, int], None] | None = None, chunk: int = 50_000
    ) -> EstimateBatch:
        """All merged steps (batch path). ``progress(done, total)`` is called every ``chunk`` steps."""
        biased = replace(steps, gyr=steps.gyr - np.asarray(self._bias))
        f = self.prefilter.run(biased)
        mag, flags = f.mag, f.flags
        if self.gate is not None:
            mag = self.gate.run(steps.h, f.acc, f.mag)
            flags = flags | np.where(
                np.isnan(mag[:, 0]) & ~np.isnan(f.mag[:, 0]), int(StepFlag.MAG_DISTURBED), 0
            )
        mag = _horizontal_rows(f.acc, mag) if self.config.magnetometer == "horizontal" else mag
        filtered = replace(f, mag=mag, flags=flags)
        start = 0
        if self._awaiting_measurement:
            both = _both_usable_rows(filtered.acc, filtered.mag, self.estimator.params)
            start = int(np.argmax(both)) if both.any() else len(steps)
        parts = []
        bounds = sorted({0, start, len(steps), *range(chunk, len(steps), chunk)})
        for i, j in zip(bounds[:-1], bounds[1:], strict=True):
            if i == start and self._awaiting_measurement:
                self._awaiting_measurement = False
                r0 = wahba(self.config.params, filtered.acc[i], filtered.mag[i])
                self.estimator.reset(r0, self.config.omega_err0)
            parts.append(self.estimator.update_batch(filtered.rows(i, j)))
            if progress is not None:
                progress(j, len(steps))
        if not parts:
            return self.estimator.update_batch(filtered)
        return _concat(parts)


def _horizontal_f(acc: Vec3 | None, mag: Vec3 | None) -> Vec3 | None:
    """The part of ``mag`` perpendicular to ``acc`` (None if either is missing)."""
    if acc is None or mag is None:
        return None
    n2 = acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2]
    if not n2 > 0.0:
        return None
    k = (mag[0] * acc[0] + mag[1] * acc[1] + mag[2] * acc[2]) / n2
    return (mag[0] - k * acc[0], mag[1] - k * acc[1], mag[2] - k * acc[2])


def _horizontal_rows(acc: Array, mag: Array) -> Array:
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.sum(mag * acc, axis=1) / np.sum(acc * acc, axis=1)
    return mag - k[:, None] * acc


def _both_usable(acc: Vec3 | None, mag: Vec3 | None, p: EstimatorParams) -> bool:
    if acc is None or mag is None:
        return False
    return bool(_both_usable_rows(np.array([acc]), np.array([mag]), p)[0])


def _both_usable_rows(acc: Array, mag: Array, p: EstimatorParams) -> NDArray[np.bool_]:
    """Rows where both directions are finite, non-zero and not within the degeneracy angle."""
    na, nm = np.linalg.norm(acc, axis=1), np.linalg.norm(mag, axis=1)
    ok = np.isfinite(na) & np.isfinite(nm) & (na > 0) & (nm > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        sin = np.linalg.norm(np.cross(acc, mag), axis=1) / (na * nm)
    return ok & (sin >= math.sin(math.radians(p.min_direction_angle_deg)))
