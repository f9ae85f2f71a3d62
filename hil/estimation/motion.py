"""How the phone is moving, from its own sensors: rest detection (which speeds the gyro bias estimate up)
and the accelerometer's trust (the strapdown pre-filter's cut-off, high when the phone is calm, low when
it is shaken). Compiled kernels the attitude filter's chain (:mod:`hil.estimation.chain`) runs every step;
pure math, no I/O.

Both look at deviations of a signal from its own low-pass (first-order, time constant ``tau_s``):

- the gyroscope's, ``‖Ω^m − lp(Ω^m)‖`` in the body frame;
- the accelerometer's, ``‖R_g a − lp(R_g a)‖`` in the strapdown frame ``R_g`` of the pre-filter (the gyro
  integrated alone): turning the phone slowly does not change what it sees of gravity there, shaking it
  does. The squared deviations are low-passed too (``dg²``, ``da²``).

**Rest**: ``√dg² < rest_gyr`` and ``√da² < rest_acc`` and the low-passed rate within ``rate_max`` of the
bias estimate, continuously for ``rest_min_s``. At rest the true rate is zero, so the gyroscope reads its
bias: the chain moves b̂ toward ``lp(Ω^m)`` at the rate ``rest_gain`` (1/s) — a direct measurement of the
bias, which only ever shrinks the bias error (docs/estimator.md, "Gyro bias").

**Accelerometer trust**: the strapdown pre-filter's accelerometer cut-off is multiplied by
``scale = dynamic + (calm − dynamic) / (1 + da²/acc_scale²)``: ``calm`` when the accelerometer sees
gravity alone, falling to ``dynamic`` as the phone is shaken (``acc_scale`` m/s² the deviation at which
it is half-way).

Arrays (float64; slots are the constants below): parameters ``mp`` (:data:`MP_SIZE`), state ``ms``
(:data:`MS_SIZE`): running flag, lp(Ω^m) (3), lp(R_g a) (3), dg², da², seconds at rest so far, rest flag,
the accelerometer cut-off scale for the next step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from hil.estimation.slots import pack
from hil.jit import kernel
from protocol.errors import ConfigError

Array = NDArray[np.float64]

MP_TAU = 0  # s, the low-passes' time constant
MP_REST_GYR = 1  # rad/s
MP_REST_ACC = 2  # m/s²
MP_REST_MIN = 3  # s
MP_RATE_MAX = 4  # rad/s: |lp(Ω^m) − b̂| above this is a turn, not rest
MP_REST_GAIN = 5  # 1/s: how fast b̂ follows lp(Ω^m) at rest (0: not at all)
MP_CALM = 6  # accelerometer cut-off scale when calm
MP_DYNAMIC = 7  # ... when shaken
MP_ACC_SCALE = 8  # m/s²: the deviation at which the scale is half-way
MP_SIZE = 9

MS_RUNNING = 0
MS_GYR_LP = 1  # (3)
MS_ACC_LP = 4  # (3), strapdown frame
MS_DG2 = 7
MS_DA2 = 8
MS_REST_FOR = 9  # s
MS_REST = 10  # 1 at rest
MS_ACC_CUT = 11  # the accelerometer cut-off scale for the next step
MS_CALM = 12  # 1 / (1 + da²/acc_scale²): 1 when the accelerometer reads gravity alone, → 0 when shaken
MS_SIZE = 13


@dataclass(frozen=True)
class MotionSettings:
    """Rest detection and accelerometer trust (see the module docstring); units: s, rad/s, m/s², 1/s.

    ``rest_gain`` 0 turns the rest update of the bias off; ``calm == dynamic == 1`` keeps the pre-filter's
    cut-off as configured."""

    tau_s: float = 0.5
    rest_gyr: float = 0.035
    rest_acc: float = 0.5
    rest_min_s: float = 1.5
    rate_max: float = 0.05
    rest_gain: float = 0.5
    calm: float = 1.0
    dynamic: float = 1.0
    acc_scale: float = 1.0


def pack_motion_params(s: MotionSettings) -> Array:
    """The parameters ``mp`` (:data:`MP_SIZE`); ConfigError naming a setting out of range."""
    positive = ("tau_s", "rest_gyr", "rest_acc", "rate_max", "calm", "dynamic", "acc_scale")
    for name, v in vars(s).items():
        ok = math.isfinite(v) and (v > 0 if name in positive else v >= 0)
        if not ok:
            sign = "positive" if name in positive else "non-negative"
            raise ConfigError(f"must be a {sign} number, got {v!r}", f"MotionSettings.{name}")
    return pack(
        MP_SIZE,
        {
            MP_TAU: s.tau_s,
            MP_REST_GYR: s.rest_gyr,
            MP_REST_ACC: s.rest_acc,
            MP_REST_MIN: s.rest_min_s,
            MP_RATE_MAX: s.rate_max,
            MP_REST_GAIN: s.rest_gain,
            MP_CALM: s.calm,
            MP_DYNAMIC: s.dynamic,
            MP_ACC_SCALE: s.acc_scale,
        },
    )


def new_motion_state() -> Array:
    """A motion state ``ms`` before the first step (cut-off scale 1)."""
    ms = np.zeros(MS_SIZE)
    ms[MS_ACC_CUT] = ms[MS_CALM] = 1.0
    return ms


@kernel
def _low_pass(ms, lp, d2, k, x, y, z):  # type: ignore[no-untyped-def]
    """One step of gain ``k`` of the low-pass ``ms[lp:lp + 3]`` towards ``(x, y, z)``, and of the low-passed
    squared distance ``ms[d2]`` between them (how much the signal moves about its mean)."""
    dx, dy, dz = x - ms[lp], y - ms[lp + 1], z - ms[lp + 2]
    ms[d2] += k * (dx * dx + dy * dy + dz * dz - ms[d2])
    ms[lp] += k * dx
    ms[lp + 1] += k * dy
    ms[lp + 2] += k * dz


@kernel
def motion_step(mp, ms, h, gx, gy, gz, bx, by, bz, ax, ay, az):  # type: ignore[no-untyped-def]
    """One step of ``h`` s: raw gyro ``g`` (rad/s; NaN: not usable), the bias estimate ``b``, the
    accelerometer in the strapdown frame ``a`` (m/s²; NaN: not usable). Updates the state: rest (its flag
    and how long) and the accelerometer cut-off scale for the next step. Returns 1 at rest, else 0.
    A sensor that is not usable ends rest and leaves its low-pass where it was."""
    g_ok = math.isfinite(gx + gy + gz)
    a_ok = math.isfinite(ax + ay + az)
    if ms[MS_RUNNING] == 0.0:
        if not (g_ok and a_ok):
            return 0
        ms[MS_RUNNING] = 1.0
        ms[MS_GYR_LP], ms[MS_GYR_LP + 1], ms[MS_GYR_LP + 2] = gx, gy, gz
        ms[MS_ACC_LP], ms[MS_ACC_LP + 1], ms[MS_ACC_LP + 2] = ax, ay, az
        return 0
    k = min(1.0, h / mp[MP_TAU])
    if g_ok:
        _low_pass(ms, MS_GYR_LP, MS_DG2, k, gx, gy, gz)
    if a_ok:
        _low_pass(ms, MS_ACC_LP, MS_DA2, k, ax, ay, az)
    calm, dyn = mp[MP_CALM], mp[MP_DYNAMIC]
    ms[MS_CALM] = 1.0 / (1.0 + ms[MS_DA2] / (mp[MP_ACC_SCALE] * mp[MP_ACC_SCALE]))
    ms[MS_ACC_CUT] = dyn + (calm - dyn) * ms[MS_CALM]
    rx, ry, rz = ms[MS_GYR_LP] - bx, ms[MS_GYR_LP + 1] - by, ms[MS_GYR_LP + 2] - bz
    lim_g, lim_a, lim_r = mp[MP_REST_GYR], mp[MP_REST_ACC], mp[MP_RATE_MAX]
    still = (
        g_ok
        and a_ok
        and ms[MS_DG2] < lim_g * lim_g
        and ms[MS_DA2] < lim_a * lim_a
        and rx * rx + ry * ry + rz * rz < lim_r * lim_r
    )
    if not still:
        ms[MS_REST_FOR] = 0.0
        ms[MS_REST] = 0.0
        return 0
    ms[MS_REST_FOR] += h
    ms[MS_REST] = 1.0 if ms[MS_REST_FOR] >= mp[MP_REST_MIN] else 0.0
    return int(ms[MS_REST])
