"""Motor torques for the compiled plant (:mod:`.compiled`): none, a held pair, or first-order motor drives,
as flat data and one compiled law evaluated at every integrator stage.

The drives are those of :class:`.servos.ServoModel` (its numpy ``__call__`` is the
reference; ``ServoModel.drive()`` packs its parameters and held setpoints into a :class:`Drive`)::

    u_γ = sat(J_γ (γ̇_sp − γ̇) / τ_γ − ρ ∂T/∂γ, u_γmax)        u_φ = sat(J_φ (φ̇_sp − φ̇) / τ_φ − ρ ∂T/∂φ, u_φmax)

with ``τ_φ`` the coasting time constant when the rotor is above its setpoint and the ESC cannot brake.
Per unit, a gimbal may follow an angle instead of a rate (the servo's own position loop,
``γ̇_sp = sat(rem(γ_sp − γ, 2π) / τ_pos, γ̇max)``) and a rotor may be undriven (no pulses, a dead ESC:
no motor torque, it coasts down against its drag, ``u_φ = −J_φ φ̇ / τ_coast``; it keeps its speed when
there is no coasting model). Both are evaluated at every stage, so the trajectory does not depend on how
often the caller refreshes the setpoints.

Why the law is a kernel of its own beside the plant rather than a method of ``ServoModel``: the compiled
step calls it at each stage, and a compiled function handed another as an argument is compiled afresh in
every process (numba keys its disk cache on the function object), so the plant's kernel names its one
torque law directly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.jit import kernel
from protocol.errors import ConfigError

Array = NDArray[np.float64]

NONE, CONSTANT, SERVO = 0, 1, 2
"""Drive modes: no motor torque; a held ``(gimbal, rotor)`` torque pair; first-order servo drives."""

# Servo header, then six rows of n: inertias, then the command (held setpoints and their modes)
_RHO, _TAU_G, _TAU_R, _TAU_COAST, _G_MAX, _R_MAX, _TAU_POS, _RATE_MAX = range(8)
HEADER = 8
_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class Drive:
    """Motor torques in the compiled plant's terms: ``mode`` (:data:`NONE`, :data:`CONSTANT`, :data:`SERVO`)
    and ``data`` (float64, flat). CONSTANT: gimbal torques (n) then rotor torques (n), N m. SERVO: the
    header ``[ρ, τ_γ, τ_φ, τ_coast (0: the ESC brakes), u_γmax, u_φmax, τ_pos, γ̇max]`` then six rows of n:
    gimbal inertias J_γ, rotor spin inertias J_φ (kg m²), gimbal setpoints (rad/s, or rad in angle mode),
    angle mode (1.0 / 0.0), rotor speed setpoints (rad/s), rotor undriven (1.0 / 0.0)."""

    mode: int
    data: Array

    @classmethod
    def none(cls) -> Drive:
        return cls(NONE, np.zeros(0))

    @classmethod
    def constant(cls, gimbal: ArrayLike, rotor: ArrayLike, n: int) -> Drive:
        """Held torques (N m), each broadcast to (n,) (a (1, n) batch of one is accepted)."""
        try:
            g = np.broadcast_to(np.asarray(gimbal, dtype=float), (1, n))[0]
            r = np.broadcast_to(np.asarray(rotor, dtype=float), (1, n))[0]
        except ValueError as e:
            raise ConfigError(f"needs {n} gimbal and rotor torques for one run: {e}", "Drive.constant") from e
        return cls(CONSTANT, np.concatenate([g, r]))

    @classmethod
    def servo(
        cls,
        header: tuple[float, float, float, float, float, float, float, float],
        gimbal_inertia: ArrayLike,
        spin_inertia: ArrayLike,
        gimbal_setpoint: ArrayLike,
        angle_mode: ArrayLike,
        rotor_setpoint: ArrayLike,
        rotor_undriven: ArrayLike,
    ) -> Drive:
        """First-order drives (see the class docstring for the fields; every row (n,))."""
        rows = [gimbal_inertia, spin_inertia, gimbal_setpoint, angle_mode, rotor_setpoint, rotor_undriven]
        arrays = [np.asarray(r, dtype=float).reshape(-1) for r in rows]
        if len({a.size for a in arrays}) != 1:
            raise ConfigError(f"rows of unequal length {[a.size for a in arrays]}", "Drive.servo")
        return cls(SERVO, np.concatenate([np.asarray(header, dtype=float), *arrays]))

    def units(self) -> int | None:
        """The unit count the data is for (None: any)."""
        if self.mode == NONE:
            return None
        return self.data.size // 2 if self.mode == CONSTANT else (self.data.size - HEADER) // 6


@kernel
def drive_torques(
    mode: int,
    drive: Array,
    n: int,
    ga: Array,
    gr: Array,
    wr: Array,
    fg: Array,
    fp: Array,
    ug: Array,
    us: Array,
) -> bool:
    """Motor torques ``ug, us`` (n,) N m at gimbal angles ``ga``, gimbal rates ``gr``, rotor rates ``wr`` and
    gyroscopic loads ``fg, fp`` (n,) for a :class:`Drive` ``(mode, drive)``; False if any is not finite."""
    if mode == NONE:
        for i in range(n):
            ug[i] = 0.0
            us[i] = 0.0
        return True
    if mode == CONSTANT:
        for i in range(n):
            ug[i] = drive[i]
            us[i] = drive[n + i]
    else:
        rho, tau_g, tau_r, tau_c = drive[_RHO], drive[_TAU_G], drive[_TAU_R], drive[_TAU_COAST]
        gmax, rmax, tau_pos, rate_max = drive[_G_MAX], drive[_R_MAX], drive[_TAU_POS], drive[_RATE_MAX]
        b = HEADER
        for i in range(n):
            jg, js = drive[b + i], drive[b + n + i]
            sp = drive[b + 2 * n + i]
            if drive[b + 3 * n + i] != 0.0:  # the servo's position loop toward an angle
                err = sp - ga[i]
                err = (err - _TWO_PI * np.rint(err / _TWO_PI)) / tau_pos
                sp = -rate_max if err < -rate_max else rate_max if err > rate_max else err
            u = jg * (sp - gr[i]) / tau_g - rho * fg[i]
            ug[i] = -gmax if u < -gmax else gmax if u > gmax else u  # NaN passes, as np.clip's
            if drive[b + 5 * n + i] != 0.0:  # undriven: no motor torque, drag alone (no coast model: none)
                us[i] = -js * wr[i] / tau_c if tau_c > 0.0 else 0.0
                continue
            e = drive[b + 4 * n + i] - wr[i]
            u = js * e / (tau_c if (tau_c > 0.0 and e < 0.0) else tau_r) - rho * fp[i]
            us[i] = -rmax if u < -rmax else rmax if u > rmax else u
    for i in range(n):
        if not (math.isfinite(ug[i]) and math.isfinite(us[i])):
            return False
    return True
