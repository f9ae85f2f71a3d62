"""The attitude filter as it runs on a phone's merged steps: gyro bias removal, the pre-filter, the
magnetic gate, the magnetometer's handling (full field or horizontal part) and the measured initial
attitude around :class:`hil.estimation.estimator.VariationalEstimator` (:class:`AttitudeFilter`), set up
by :class:`FilterConfig` with the paper's or the tuned (:data:`TUNED`) settings. The steps themselves
are the compiled kernels of :mod:`hil.estimation.chain`. Pure math, no I/O."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation import chain
from hil.estimation.estimator import Estimate, EstimateBatch, VariationalEstimator, estimate
from hil.estimation.inertial import directions_from_dip
from hil.estimation.params import EstimatorParams
from hil.estimation.prefilter import (
    PAPER_CUTOFF_RAD_S,
    SS_N,
    GateSettings,
    pack_gate_params,
    pack_signal_params,
)
from hil.estimation.sensors import KINDS, MergedStep, MergedSteps, SensorKind, StepFlag, as_vec3
from hil.estimation.variational import S_OMEGA
from protocol.errors import ConfigError, ConvergenceError

Array = NDArray[np.float64]

_NAN3 = (math.nan, math.nan, math.nan)
_NEWTON_FAILED = int(StepFlag.NEWTON_FAILED)


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
    :meth:`step` live (one :class:`MergedStep`, one compiled call), :meth:`run` in batch
    (:class:`MergedSteps`, one compiled call per ``chunk`` steps); both run the same kernel
    (:mod:`hil.estimation.chain`) and give the same numbers.

    With ``init="measured"`` the estimator (re)starts at the first step where both directions are usable,
    from Wahba's solution for that step's (pre-filtered) measurement; steps before it run from identity.
    """

    def __init__(self, config: FilterConfig | None = None) -> None:
        self.config = cfg = config or FilterConfig()
        init = cfg.init
        r0 = None if isinstance(init, str) else init
        self.estimator = VariationalEstimator(cfg.params, r0, cfg.omega_err0)
        self._ep, self._es = self.estimator.arrays
        signal = pack_signal_params(cfg.prefilter_rad_s, cfg.prefilter_frame)
        gate = None if cfg.mag_gate is None else pack_gate_params(cfg.mag_gate)
        self._cp = chain.pack_params(signal, gate, cfg.magnetometer == "horizontal", cfg.omega_err0)
        self._cs = chain.new_state(cfg.gyro_bias, isinstance(init, str) and init == "measured")
        self._raise = cfg.params.on_newton_failure == "raise"

    def set_gyro_bias(self, bias: ArrayLike) -> None:
        """Subtract ``bias`` (3,) rad/s from every later gyro sample: a bias measured while running (the
        host's still window) — the estimator's attitude would otherwise carry a steady offset from it."""
        b = as_vec3(tuple(np.asarray(bias, dtype=float).tolist()))
        if b is None:
            raise ConfigError(f"must be a finite 3-vector, got {bias!r}", "AttitudeFilter.set_gyro_bias")
        self._cs[chain.CS_BIAS : chain.CS_BIAS + 3] = b

    def step(self, s: MergedStep) -> Estimate:
        """One merged step (live path)."""
        gx, gy, gz = _NAN3 if s.gyr is None else s.gyr
        ax, ay, az = _NAN3 if s.acc is None else s.acc
        mx, my, mz = _NAN3 if s.mag is None else s.mag
        es = self._es
        snapshot = self._snapshot() if self._raise else None
        code = chain.step(self._cp, self._cs, self._ep, es, s.t, s.h, gx, gy, gz, ax, ay, az, mx, my, mz)
        if code < 0:
            raise ValueError(f"filter step must be positive, got h = {s.h!r} s (t = {s.t!r} s)")
        if snapshot is not None and code & _NEWTON_FAILED:
            self._fail(snapshot, s.t, s.h)
        return estimate(s.t, es, code, int(s.flags))

    def run(
        self, steps: MergedSteps, progress: Callable[[int, int], None] | None = None, chunk: int = 50_000
    ) -> EstimateBatch:
        """All merged steps (batch path), continuing from the current state: one compiled call per
        ``chunk`` steps, after which ``progress(done, total)`` is called."""
        n = len(steps)
        t = np.ascontiguousarray(steps.t, dtype=float)
        cs = self._cs
        if n and not np.all(np.diff(t) > 0):
            i = int(np.flatnonzero(~(np.diff(t) > 0))[0])
            raise ValueError(f"filter run: step times must increase strictly (step {i + 1}: {t[i + 1]!r})")
        if n and cs[chain.CS_SIGNAL + SS_N] and not t[0] > cs[chain.CS_T]:
            raise ValueError(
                f"filter run: first step time {t[0]!r} is not after the last one, {cs[chain.CS_T]!r}"
            )
        out = EstimateBatch(
            t.copy(), np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.int64),
            np.empty(n, np.int64),
        )  # fmt: skip
        flags = np.ascontiguousarray(steps.flags, dtype=np.int64)
        gyr, acc, mag = (np.ascontiguousarray(a, dtype=float) for a in (steps.gyr, steps.acc, steps.mag))
        ep, es = self.estimator.arrays
        snapshot = self._snapshot() if self._raise else None
        for i in range(0, n, chunk):
            j = min(i + chunk, n)
            done = chain.run(
                self._cp, cs, ep, es, t[i:j], flags[i:j], gyr[i:j], acc[i:j], mag[i:j],
                out.R[i:j], out.omega[i:j], out.omega_err[i:j], out.flags[i:j], out.iterations[i:j],
            )  # fmt: skip
            if snapshot is not None and done and out.flags[i + done - 1] & _NEWTON_FAILED:
                k = i + done - 1
                self._fail(snapshot, float(t[k]), float(t[k] - t[k - 1]) if k else 0.0)
            if progress is not None:
                progress(j, n)
        return out

    def _snapshot(self) -> tuple[Array, Array]:
        return self._cs.copy(), self.estimator.arrays[1].copy()

    def _fail(self, snapshot: tuple[Array, Array], t: float, h: float) -> None:
        """Undo the call (the filter is as it was before it) and raise the Newton failure."""
        es = self.estimator.arrays[1]
        w = es[S_OMEGA : S_OMEGA + 3].tolist()
        self._cs[:], es[:] = snapshot
        p = self.config.params
        raise ConvergenceError(
            f"estimator step at t = {t:g} s (h = {h:g} s): Newton–Raphson did not reach "
            f"{p.newton_tol:g} rad/s in {p.newton_max_iter} updates (ω = {w})"
        )
