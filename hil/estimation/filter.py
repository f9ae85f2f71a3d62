"""The attitude filter as it runs on a phone's merged steps: the pre-filter, rest detection and the
accelerometer's trust, magnetic disturbance handling, the magnetometer's use (full field, horizontal part,
or none: 6-axis) and the measured initial attitude around :class:`hil.estimation.estimator.
VariationalEstimator` with its online gyro bias estimate (:class:`AttitudeFilter`), set up by
:class:`FilterConfig` with the paper's or the tuned (:data:`TUNED`) settings. The steps themselves are
the compiled kernels of :mod:`hil.estimation.chain`. Pure math, no I/O."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import jit
from hil.estimation import chain
from hil.estimation.estimator import Estimate, EstimateBatch, VariationalEstimator, check_times, estimate
from hil.estimation.inertial import directions_from_dip
from hil.estimation.magnetic import MagneticSettings, pack_mag_params
from hil.estimation.motion import MP_REST_GAIN, MotionSettings, pack_motion_params
from hil.estimation.params import EstimatorParams
from hil.estimation.prefilter import PAPER_CUTOFF_RAD_S, SS_N, pack_signal_params
from hil.estimation.sensors import KINDS, MergedStep, MergedSteps, SensorKind, as_vec3
from hil.estimation.slots import MAX_SUBSTEPS, NEWTON_FAILED
from hil.estimation.variational import S_BIAS, S_OMEGA
from protocol.errors import ConfigError, ConvergenceError

Array = NDArray[np.float64]

_NAN3 = (math.nan, math.nan, math.nan)
_MAG_MODES = {"full": chain.MAG_FULL, "horizontal": chain.MAG_HORIZONTAL, "none": chain.MAG_NONE}


PAPER_PREFILTER: dict[SensorKind, float | None] = {k: PAPER_CUTOFF_RAD_S for k in KINDS}
"""The paper's pre-filter: every measured quantity through the 1 rad/s first-order Butterworth."""


@dataclass(frozen=True)
class FilterConfig:
    """The estimator as it runs on a phone's merged steps: what happens to the measurements first.

    ``prefilter_rad_s``: pre-filter cut-off per sensor (rad/s), None for none; ``prefilter_frame``
    ``"body"`` (the paper) or ``"strapdown"`` (see :class:`hil.estimation.prefilter.SignalPrefilter`).
    ``gyro_bias`` (3,) rad/s: the initial gyro bias estimate b̂0 (e.g. measured over a still window: an
    optional initialiser), corrected online when ``params.bias_gain`` is not zero (and at rest with
    ``motion``); with a zero gain it is subtracted as given.
    ``magnetometer``: ``"full"`` uses the field direction as measured (the paper; E's e2 is the full field
    direction); ``"horizontal"`` uses its component perpendicular to the measured gravity direction, so that
    the magnetometer informs heading only (E's e2 must then be horizontal, e.g. magnetic north); ``"none"``
    does not use it (6-axis: inclination from gravity, heading the bias-corrected gyro's integral).
    ``init``: initial attitude — ``"measured"`` (Wahba's solution from the first step with both directions;
    from gravity alone, heading where it lands, until there is a field), ``"identity"``, or a (3, 3)
    body → inertial matrix; ``omega_err0`` (3,) rad/s the initial ω.
    ``mag_gate``: magnetic disturbance handling (:mod:`hil.estimation.magnetic`), or None (every field
    sample used). ``motion``: rest detection and accelerometer trust (:mod:`hil.estimation.motion`), or
    None (neither). ``settle_s``: with a measured initial attitude, for this long after it (s) the
    estimator restarts from Wahba's solution at every step where both directions are usable, while the
    pre-filter averages out the first readings (a recording that starts mid-motion: see
    docs/estimator.md, "Starting mid-motion"); 0: it runs from the first measurement on its own.
    """

    params: EstimatorParams = field(default_factory=EstimatorParams)
    prefilter_rad_s: dict[SensorKind, float | None] = field(default_factory=lambda: dict(PAPER_PREFILTER))
    prefilter_frame: Literal["body", "strapdown"] = "body"
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    magnetometer: Literal["full", "horizontal", "none"] = "full"
    init: Literal["measured", "identity"] | ArrayLike = "measured"
    omega_err0: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_gate: MagneticSettings | None = None
    motion: MotionSettings | None = None
    settle_s: float = 0.0

    def __post_init__(self) -> None:
        if self.magnetometer not in _MAG_MODES:
            raise ConfigError(
                f"must be 'full', 'horizontal' or 'none', got {self.magnetometer!r}",
                "FilterConfig.magnetometer",
            )
        if self.magnetometer == "horizontal" and abs(float(self.params.E[2, 1])) > 1e-9:
            raise ConfigError(
                "a horizontal magnetometer needs a horizontal e2 (E[2, 1] = 0)", "FilterConfig.params.E"
            )
        if as_vec3(self.gyro_bias) is None:
            raise ConfigError(f"must be a finite 3-vector, got {self.gyro_bias!r}", "FilterConfig.gyro_bias")
        if isinstance(self.init, str) and self.init not in ("measured", "identity"):
            raise ConfigError(f"must be 'measured', 'identity' or a 3x3 matrix, got {self.init!r}", "init")
        settle = self.settle_s
        if isinstance(settle, bool) or not (isinstance(settle, (int, float)) and 0.0 <= settle < math.inf):
            raise ConfigError(
                f"must be a finite number of seconds, 0 or more, got {self.settle_s!r}",
                "FilterConfig.settle_s",
            )

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
        params = EstimatorParams(
            E=directions_from_dip(0.0, declination_deg),
            W=np.diag(TUNED["W_diag"]),
            m=TUNED["m"],
            D=np.diag(TUNED["D_diag"]),
            bias_gain=(TUNED["bias_gain"],) * 3,
            bias_max=TUNED["bias_max"],
            bias_vertical=TUNED["bias_vertical"],
            gyro_delay_s=TUNED["gyro_delay_s"],
            max_step_s=TUNED["max_step_s"],
        )
        cut = {SensorKind.ACC: TUNED["acc_cutoff"], SensorKind.MAG: TUNED["mag_cutoff"], SensorKind.GYR: None}
        base = {
            "params": params,
            "prefilter_rad_s": cut,
            "prefilter_frame": "strapdown",
            "magnetometer": "horizontal",
            "mag_gate": TUNED["mag_gate"],
            "motion": TUNED["motion"],
            "settle_s": TUNED["settle_s"],
        }
        return cls(**{**base, **overrides})  # type: ignore[arg-type]


TUNED: dict = {
    "W_diag": (4.0, 0.4, 0.05),
    "m": 0.1,
    "D_diag": (6.0, 6.5, 7.0),
    "acc_cutoff": 0.47,
    "mag_cutoff": None,
    "bias_gain": 0.003,
    "bias_vertical": 1.5,
    "bias_max": 0.05,
    "gyro_delay_s": 0.005,
    "mag_gate": MagneticSettings(norm_tol=0.3, dip_tol_deg=15.0, late_weight=0.5, boost=6.0),
    "motion": MotionSettings(acc_scale=2.0, calm=1.0, dynamic=1.0, rest_gain=0.5),
    "settle_s": 8.0,
    "max_step_s": 0.006,
}
"""Tuned settings: chosen by leave-one-trial-out over every shared trial (``python -m bench.bench_estimator
--tune``); see docs/estimator.md, "The tuned preset"."""


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
        self.estimator = VariationalEstimator(cfg.params, r0, cfg.omega_err0, cfg.gyro_bias)
        self._ep, self._es = self.estimator.arrays
        signal = pack_signal_params(cfg.prefilter_rad_s, cfg.prefilter_frame, cfg.params.gyro_delay_s)
        gate = None if cfg.mag_gate is None else pack_mag_params(cfg.mag_gate)
        motion = None if cfg.motion is None else pack_motion_params(cfg.motion)
        mode = _MAG_MODES[cfg.magnetometer]
        self._cp = chain.pack_params(signal, gate, mode, cfg.omega_err0, motion, float(cfg.settle_s))
        self._cs = chain.new_state(cfg.gyro_bias, isinstance(init, str) and init == "measured")
        self._raise = cfg.params.on_newton_failure == "raise"
        self._head = self.estimator.head
        self._step: Callable[..., int] | None = None  # chain.step's machine code, bound at the first step

    @property
    def gyro_bias(self) -> Array:
        """The gyro bias estimate b̂ (3,), rad/s."""
        return self._es[S_BIAS : S_BIAS + 3].copy()

    def set_gyro_bias(self, bias: ArrayLike) -> None:
        """Set the gyro bias estimate to ``bias`` (3,) rad/s, measured while running (the host's still
        window): the estimator continues from it (and keeps correcting it, given a bias gain)."""
        b = as_vec3(tuple(np.asarray(bias, dtype=float).tolist()))
        if b is None:
            raise ConfigError(f"must be a finite 3-vector, got {bias!r}", "AttitudeFilter.set_gyro_bias")
        self._cs[chain.CS_BIAS : chain.CS_BIAS + 3] = b
        self._es[S_BIAS : S_BIAS + 3] = b

    def set_rest_learning(self, enabled: bool) -> None:
        """Let rest detection pull the bias estimate toward the gyro (the settings' ``rest_gain``) or not
        (0), from the next step on; rest is still detected and flagged. For a caller that knows better
        than the detector: the host, whose spacecraft ending a slew under control turns steadily below
        ``rate_max`` — what the detector takes for rest —, learns only in its still window."""
        if self.config.motion is not None:
            gain = self.config.motion.rest_gain if enabled else 0.0
            self._cp[chain.CP_MOTION + MP_REST_GAIN] = gain

    def step(self, s: MergedStep) -> Estimate:
        """One merged step (live path)."""
        gx, gy, gz = _NAN3 if s.gyr is None else s.gyr
        ax, ay, az = _NAN3 if s.acc is None else s.acc
        mx, my, mz = _NAN3 if s.mag is None else s.mag
        es = self._es
        snapshot = self._snapshot() if self._raise else None
        step = self._step
        if step is None:  # not at construction: a filter that only runs batches never needs it
            step = self._step = jit.direct(chain.step, self._cp, self._cs, self._ep, es, *([0.0] * 11))
        code = step(self._cp, self._cs, self._ep, es, s.t, s.h, gx, gy, gz, ax, ay, az, mx, my, mz)
        if code < 0:
            longest = self.estimator.longest_step_s
            raise ValueError(
                f"filter step must be a positive number of seconds, at most {longest:.6g} "
                f"({MAX_SUBSTEPS} sub-steps of max_step_s), got h = {s.h!r} s (t = {s.t!r} s)"
            )
        if snapshot is not None and code & NEWTON_FAILED:
            self._fail(snapshot, s.t, s.h)
        return estimate(s.t, self._head, code, int(s.flags))

    def run(
        self, steps: MergedSteps, progress: Callable[[int, int], None] | None = None, chunk: int = 50_000
    ) -> EstimateBatch:
        """All merged steps (batch path), continuing from the current state: one compiled call per
        ``chunk`` steps, after which ``progress(done, total)`` is called."""
        n = len(steps)
        t = np.ascontiguousarray(steps.t, dtype=float)
        cs = self._cs
        last = float(cs[chain.CS_T]) if cs[chain.CS_SIGNAL + SS_N] else None
        check_times(t, last, self.estimator.longest_step_s, "filter run")
        out = EstimateBatch(
            t.copy(),
            np.empty((n, 3, 3)),
            np.empty((n, 3)),
            np.empty((n, 3)),
            np.empty(n, np.int64),
            np.empty(n, np.int64),
        )
        flags = np.ascontiguousarray(steps.flags, dtype=np.int64)
        gyr, acc, mag = (np.ascontiguousarray(a, dtype=float) for a in (steps.gyr, steps.acc, steps.mag))
        ep, es = self.estimator.arrays
        snapshot = self._snapshot() if self._raise else None
        for i in range(0, n, chunk):
            j = min(i + chunk, n)
            done = chain.run(
                self._cp,
                cs,
                ep,
                es,
                t[i:j],
                flags[i:j],
                gyr[i:j],
                acc[i:j],
                mag[i:j],
                out.R[i:j],
                out.omega[i:j],
                out.omega_err[i:j],
                out.flags[i:j],
                out.iterations[i:j],
            )
            if snapshot is not None and done and out.flags[i + done - 1] & NEWTON_FAILED:
                k = i + done - 1
                self._fail(snapshot, float(t[k]), float(t[k] - t[k - 1]) if k else 0.0)
            if done < j - i:  # a step the kernel refused, which check_times lets through: never rows unfilled
                raise ValueError(f"filter run: step {i + done} at {t[i + done]!r} s was refused")
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
