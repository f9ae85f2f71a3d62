"""Magnetic disturbances: when to leave the magnetometer out, and when to take it back. A compiled kernel
(:func:`mag_step`) the attitude filter's chain runs on every magnetometer sample, its settings
(:class:`MagneticSettings`) and an object to run it alone (:class:`MagneticGate`). Pure math, no I/O.

The geomagnetic field has a fixed strength and a fixed angle to the vertical (the dip) wherever the phone
turns; a disturbance (steel, magnets, electronics) changes one or both. The field's norm and the sine of
its dip against the vertical given (the filter's estimate of it) are low-passed (``current_tau_s``) and
compared with a *reference*:

- **Rejection.** The field is disturbed when its norm is off the reference's by more than ``norm_tol``
  (fraction) or its dip by more than ``dip_tol_deg``; it is taken back once it has been within both for
  ``min_undisturbed_s``. While it is disturbed the filter carries the heading on the bias-corrected
  gyroscope (weight 0).
- **The reference** starts at the first sample and follows undisturbed samples only (time constant
  ``tau_s``): a disturbance never drags it. The first sample may itself be disturbed (a recording that
  starts next to a magnet): until the field has agreed with it for ``first_steady_s`` of turning, a
  candidate needs only that long to replace it.
- **Time-outs that cannot lock in a disturbed field.** A disturbance that lasts may be a new environment.
  The field is tracked as a *candidate* reference, which restarts whenever a sample leaves it. While
  disturbed, the candidate replaces the reference only if it has held steady for ``steady_s`` of turning
  (time with the rate above ``min_rate``: a field that keeps its strength and dip while the phone turns is
  homogeneous, not a magnet nearby — which changes as the phone moves — nor one carried with the phone,
  whose dip changes as it turns) and its strength is a geomagnetic one (``field_min`` to ``field_max``,
  the magnetometer's unit, µT). The replaced reference is kept: a field consistent with it again makes it
  the reference again at once. A disturbance that outlasts ``max_rejection_s`` — a budget that refills at
  ``recovery`` times the rate it is spent while the field is undisturbed, and starts spent: until the
  filter has seen the field agree with its first sample for a while, that sample may be the odd one —
  has the field used again at ``late_weight``, bounding the gyroscope's drift, but only while its
  strength is a geomagnetic one; the reference stays where it was.

Arrays (float64; slots are the constants below): parameters ``gp`` (:data:`GP_SIZE`), state ``gs``
(:data:`GS_SIZE`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation.slots import pack
from hil.jit import kernel
from protocol.errors import ConfigError

Array = NDArray[np.float64]

GP_NORM_TOL = 0  # fraction
GP_SIN_TOL = 1  # sin of the dip tolerance
GP_CURRENT_TAU = 2  # s, the low-pass of the field's norm and dip
GP_TAU = 3  # s, the reference's
GP_MIN_UNDISTURBED = 4  # s
GP_STEADY = 5  # s of turning
GP_MIN_RATE = 6  # rad/s
GP_FIELD_MIN = 7  # magnetometer unit
GP_FIELD_MAX = 8
GP_MAX_REJECTION = 9  # s
GP_RECOVERY = 10  # budget refill rate / spend rate
GP_LATE_WEIGHT = 11  # weight after the rejection budget is spent
GP_FIRST_STEADY = 12  # s of turning that confirm the first reference (or let a candidate replace it)
GP_BOOST = 13  # the field's weight at the start and after an adoption, falling back to 1
GP_BOOST_S = 14  # s, its time constant
GP_SIZE = 15

GS_STARTED = 0
GS_NORM = 1  # the low-passed norm
GS_DIP = 2  # the low-passed sin of the dip: −(v̂·m̂), v̂ the vertical (up)
GS_HAS_DIP = 3
GS_REF_NORM = 4
GS_REF_DIP = 5
GS_HAS_PREV = 6
GS_PREV_NORM = 7
GS_PREV_DIP = 8
GS_DISTURBED = 9  # 1 while disturbed
GS_UNDISTURBED_FOR = 10  # s within the tolerances
GS_REJECTED_FOR = 11  # s of the rejection budget spent
GS_CAND_NORM = 12
GS_CAND_DIP = 13
GS_CAND_FOR = 14  # s of turning the candidate has held
GS_ADOPTED = 15  # how many candidates became the reference
GS_CONFIRMED = 16  # 1 once the reference has held for first_steady_s of turning (or was adopted)
GS_CONFIRM_FOR = 17  # s of turning the (first) reference has held
GS_SINCE = 18  # s since the first sample or the last adoption
GS_SIZE = 19


@dataclass(frozen=True)
class MagneticSettings:
    """:func:`mag_step`'s settings (see the module docstring): tolerances (fraction, degrees), time
    constants and times (s), turning rate (rad/s), geomagnetic field strength bounds (the magnetometer's
    unit, µT), the budget's refill rate and the weight after it is spent (0–1)."""

    norm_tol: float = 0.1
    dip_tol_deg: float = 10.0
    current_tau_s: float = 0.05
    tau_s: float = 20.0
    min_undisturbed_s: float = 0.5
    steady_s: float = 20.0
    min_rate: float = 0.35
    field_min: float = 15.0
    field_max: float = 75.0
    max_rejection_s: float = 60.0
    recovery: float = 2.0
    late_weight: float = 0.5
    first_steady_s: float = 5.0
    boost: float = 1.0
    boost_s: float = 5.0


def pack_mag_params(s: MagneticSettings) -> Array:
    """The parameters ``gp`` (:data:`GP_SIZE`); ConfigError naming a setting out of range."""
    for name, v in vars(s).items():
        if not (math.isfinite(v) and v >= 0 and (v > 0 or name in ("min_undisturbed_s", "late_weight"))):
            raise ConfigError(f"must be a positive number, got {v!r}", f"MagneticSettings.{name}")
    if not s.late_weight <= 1.0:
        raise ConfigError(f"must be at most 1, got {s.late_weight!r}", "MagneticSettings.late_weight")
    if not s.dip_tol_deg < 90.0:
        raise ConfigError(f"must be below 90, got {s.dip_tol_deg!r}", "MagneticSettings.dip_tol_deg")
    if not s.field_min < s.field_max:
        raise ConfigError(f"{s.field_min!r} is not below {s.field_max!r}", "MagneticSettings.field_min")
    return pack(
        GP_SIZE,
        {
            GP_NORM_TOL: s.norm_tol,
            GP_SIN_TOL: math.sin(math.radians(s.dip_tol_deg)),
            GP_CURRENT_TAU: s.current_tau_s,
            GP_TAU: s.tau_s,
            GP_MIN_UNDISTURBED: s.min_undisturbed_s,
            GP_STEADY: s.steady_s,
            GP_MIN_RATE: s.min_rate,
            GP_FIELD_MIN: s.field_min,
            GP_FIELD_MAX: s.field_max,
            GP_MAX_REJECTION: s.max_rejection_s,
            GP_RECOVERY: s.recovery,
            GP_LATE_WEIGHT: s.late_weight,
            GP_FIRST_STEADY: s.first_steady_s,
            GP_BOOST: s.boost,
            GP_BOOST_S: s.boost_s,
        },
    )


@kernel
def _full(gp, gs):  # type: ignore[no-untyped-def]
    """An accepted field's weight: ``boost`` falling back to 1 after the start or an adoption."""
    return 1.0 + (gp[GP_BOOST] - 1.0) * math.exp(-gs[GS_SINCE] / gp[GP_BOOST_S])


@kernel
def _within(gp, gs, slot_norm, slot_dip):  # type: ignore[no-untyped-def]
    """Whether the low-passed field is within the tolerances of the (norm, dip) at the given slots. A norm
    of 0 there holds nothing: a low-pass from a huge field to a normal one in one step (``k`` = 1) can
    cancel to exactly 0, and a compiled kernel's division by zero raises."""
    ref = gs[slot_norm]
    if not ref > 0.0 or abs(gs[GS_NORM] / ref - 1.0) > gp[GP_NORM_TOL]:
        return False
    return gs[GS_HAS_DIP] == 0.0 or abs(gs[GS_DIP] - gs[slot_dip]) <= gp[GP_SIN_TOL]


@kernel
def mag_step(gp, gs, h, rate, ux, uy, uz, mx, my, mz):  # type: ignore[no-untyped-def]
    """The weight (0 to 1) the magnetometer sample ``m`` gets, given the vertical ``u`` (up; NaN if not
    known), the step ``h`` (s) and the turning rate ``rate`` (rad/s); updates the state (see the module
    docstring). A non-finite or zero ``m`` gets 0 and changes nothing."""
    n = math.sqrt(mx * mx + my * my + mz * mz)
    if not (n > 0.0 and math.isfinite(n)):
        return 0.0
    nu = math.sqrt(ux * ux + uy * uy + uz * uz)
    has_dip = nu > 0.0 and math.isfinite(nu)
    dip = -(ux * mx + uy * my + uz * mz) / (nu * n) if has_dip else 0.0
    if gs[GS_STARTED] == 0.0:  # the first sample: the (tentative) reference, the budget spent
        gs[GS_STARTED], gs[GS_NORM], gs[GS_DIP], gs[GS_HAS_DIP] = 1.0, n, dip, 1.0 if has_dip else 0.0
        gs[GS_REF_NORM], gs[GS_REF_DIP], gs[GS_CAND_NORM], gs[GS_CAND_DIP] = n, dip, n, dip
        gs[GS_REJECTED_FOR] = gp[GP_MAX_REJECTION]
        return _full(gp, gs)
    gs[GS_SINCE] += h
    k = min(1.0, h / gp[GP_CURRENT_TAU])
    gs[GS_NORM] += k * (n - gs[GS_NORM])
    if has_dip:
        if gs[GS_HAS_DIP] == 0.0:  # the first vertical: the references' dips start here
            gs[GS_HAS_DIP], gs[GS_DIP], gs[GS_REF_DIP], gs[GS_CAND_DIP] = 1.0, dip, dip, dip
        gs[GS_DIP] += k * (dip - gs[GS_DIP])
    if _within(gp, gs, GS_REF_NORM, GS_REF_DIP):
        gs[GS_UNDISTURBED_FOR] += h
        if rate >= gp[GP_MIN_RATE]:
            gs[GS_CONFIRM_FOR] += h
            if gs[GS_CONFIRM_FOR] >= gp[GP_FIRST_STEADY]:
                gs[GS_CONFIRMED] = 1.0
    elif gs[GS_HAS_PREV] != 0.0 and _within(gp, gs, GS_PREV_NORM, GS_PREV_DIP):
        # the field the last adopted candidate replaced is back: it is the reference again
        gs[GS_REF_NORM], gs[GS_PREV_NORM] = gs[GS_PREV_NORM], gs[GS_REF_NORM]
        gs[GS_REF_DIP], gs[GS_PREV_DIP] = gs[GS_PREV_DIP], gs[GS_REF_DIP]
        gs[GS_UNDISTURBED_FOR] += h
    else:
        gs[GS_UNDISTURBED_FOR] = 0.0
        gs[GS_DISTURBED] = 1.0
    if gs[GS_DISTURBED] != 0.0 and gs[GS_UNDISTURBED_FOR] >= gp[GP_MIN_UNDISTURBED]:
        gs[GS_DISTURBED] = 0.0
    kr = min(1.0, h / gp[GP_TAU])
    # the candidate: the field as it holds, restarted whenever it leaves it
    if _within(gp, gs, GS_CAND_NORM, GS_CAND_DIP):
        if rate >= gp[GP_MIN_RATE]:
            gs[GS_CAND_FOR] += h
        gs[GS_CAND_NORM] += kr * (gs[GS_NORM] - gs[GS_CAND_NORM])
        gs[GS_CAND_DIP] += kr * (gs[GS_DIP] - gs[GS_CAND_DIP])
    else:
        gs[GS_CAND_NORM], gs[GS_CAND_DIP], gs[GS_CAND_FOR] = gs[GS_NORM], gs[GS_DIP], 0.0
    if gs[GS_DISTURBED] == 0.0:
        gs[GS_REF_NORM] += kr * (gs[GS_NORM] - gs[GS_REF_NORM])
        gs[GS_REF_DIP] += kr * (gs[GS_DIP] - gs[GS_REF_DIP])
        gs[GS_REJECTED_FOR] = max(0.0, gs[GS_REJECTED_FOR] - gp[GP_RECOVERY] * h)
        return _full(gp, gs)
    geomagnetic = gp[GP_FIELD_MIN] <= gs[GS_NORM] <= gp[GP_FIELD_MAX]
    steady = gp[GP_STEADY] if gs[GS_CONFIRMED] != 0.0 else gp[GP_FIRST_STEADY]
    if gs[GS_CAND_FOR] >= steady and gp[GP_FIELD_MIN] <= gs[GS_CAND_NORM] <= gp[GP_FIELD_MAX]:
        # the replaced reference is remembered only if it had been confirmed (not a disturbed first sample)
        gs[GS_HAS_PREV], gs[GS_PREV_NORM], gs[GS_PREV_DIP] = gs[GS_CONFIRMED], gs[GS_REF_NORM], gs[GS_REF_DIP]
        gs[GS_CONFIRMED] = 1.0
        gs[GS_REF_NORM], gs[GS_REF_DIP] = gs[GS_CAND_NORM], gs[GS_CAND_DIP]
        gs[GS_DISTURBED], gs[GS_UNDISTURBED_FOR] = 0.0, gp[GP_MIN_UNDISTURBED]
        gs[GS_ADOPTED] += 1.0
        gs[GS_SINCE] = 0.0
        return _full(gp, gs)
    if gs[GS_REJECTED_FOR] < gp[GP_MAX_REJECTION]:
        gs[GS_REJECTED_FOR] += h
        return 0.0
    return gp[GP_LATE_WEIGHT] if geomagnetic else 0.0


@kernel
def _mag_run(gp, gs, h, rate, up, mag, weight):  # type: ignore[no-untyped-def]
    """:func:`mag_step` over N steps: ``h``, ``rate`` (N,), ``up`` and ``mag`` (N, 3), into ``weight``."""
    for i in range(h.shape[0]):
        weight[i] = mag_step(
            gp, gs, h[i], rate[i], up[i, 0], up[i, 1], up[i, 2], mag[i, 0], mag[i, 1], mag[i, 2]
        )


class MagneticGate:
    """:func:`mag_step` on its own: the weight a filter would give each magnetometer sample (the chain
    runs the same kernel inside its step)."""

    def __init__(self, settings: MagneticSettings | None = None) -> None:
        self.settings = settings or MagneticSettings()
        self._gp = pack_mag_params(self.settings)
        self._gs = np.zeros(GS_SIZE)

    @property
    def adopted(self) -> int:
        """How many candidate references were adopted so far."""
        return int(self._gs[GS_ADOPTED])

    @property
    def reference(self) -> tuple[float, float]:
        """The reference field's norm (the magnetometer's unit) and dip (degrees)."""
        return float(self._gs[GS_REF_NORM]), math.degrees(
            math.asin(max(-1.0, min(1.0, self._gs[GS_REF_DIP])))
        )

    def run(self, h: ArrayLike, rate: ArrayLike, up: ArrayLike, mag: ArrayLike) -> Array:
        """The weights of N samples: steps ``h`` (N,) s, turning rates ``rate`` (N,) rad/s, verticals ``up``
        and magnetometer samples ``mag`` (N, 3)."""
        h, rate, up, mag = (np.ascontiguousarray(a, dtype=float) for a in (h, rate, up, mag))
        weight = np.empty(len(h))
        _mag_run(self._gp, self._gs, h, rate, up, mag, weight)
        return weight
