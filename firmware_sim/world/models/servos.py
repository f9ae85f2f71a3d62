"""The drives' physics (numpy, the reference): :class:`ServoModel`, what the motor drivers do with the
host's setpoints (:class:`hil.control.motor_loops.Setpoints`) as torques on the plant
(:data:`.plant.TorqueLaw`), so a simulated world closes the loop board pulses → motor torque →
plant. Unloaded, both respond in first order with the time constants of ``firmware_sim.board.actuators``
(gimbal 0.05 s, rotor ESC 0.15 s spinning up); torques are limited to the motors' stall torques::

    u = sat(−ρ ∂T/∂q + J_q (q̇_sp − q̇) / τ, u_max)        q = γ (gimbal) or φ (rotor)

``J_q`` is the inertia the motor turns (gimbal structure plus rotor about the gimbal axis; the rotor
about its spin axis) and ``∂T/∂q`` the gyroscopic load on it. The load term (ρ = ``load_rejection``, 1 by
default) stands for the stiff inner loop of a real CMG gimbal drive (tachometer loop, gearing): the
gyroscopic reaction on a gimbal, rotor momentum times body rate, is tens of times what a proportional
term of this bandwidth could hold, and a gimbal that gave way to it would turn the array's torque into
noise. A proportional gain stiff enough to hold it instead would put a pole at ~10⁴ rad/s into the
plant. An ESC that cannot brake is modelled by a longer ``coast_time_constant_s`` when the setpoint is
below the speed.

The compiled plant runs the same law inside its integrator stages (:func:`.drives.drive_torques`);
:meth:`ServoModel.drive` packs this servo's parameters and held setpoints for it.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.control.motor_loops import ServoParams, Setpoints
from hil.vscmg import SpacecraftParams
from hil.vscmg.params import inertia_tensor
from protocol.errors import ConfigError

from .drives import SERVO, Drive

Array = NDArray[np.float64]
_TWO_PI = 2.0 * math.pi


class ServoModel:
    """Gimbal and rotor servos of every unit as a :data:`.plant.TorqueLaw` (numpy, batched): call
    :meth:`hold` with the current setpoints and pass the instance to ``Plant.step``. The compiled plant
    (:class:`.compiled.CompiledPlant`) takes it too: :meth:`drive` packs the same law for its kernel
    (:func:`.drives.drive_torques`, which this class's ``__call__`` is the reference of).

    Beyond the rate setpoints of :class:`Setpoints`, :meth:`hold` takes per unit an angle mode (the gimbal
    servo's own position loop toward a target angle, ``γ̇_sp = sat(rem(γ_sp − γ, 2π) / τ_pos, γ̇max)``) and
    undriven rotors (no pulses or a dead ESC: no motor torque; the rotor coasts down against its drag with
    the coasting time constant, ``u_φ = −J_φ φ̇ / τ_coast`` — as the board's own unit model has it — or keeps
    its speed when the servo has no coasting model)."""

    def __init__(self, params: SpacecraftParams, servo: ServoParams | None = None) -> None:
        self.params = params
        self.servo = servo or ServoParams()
        units = params.units
        ig = [inertia_tensor(u.gimbal_inertia, "gimbal_inertia")[2, 2] for u in units]
        iw = [inertia_tensor(u.rotor_inertia, "rotor_inertia")[2, 2] for u in units]
        self.gimbal_inertia = np.array(ig) + np.array(iw)
        self.spin_inertia = np.array([u.rotor_spin_inertia for u in units])
        n = len(units)
        self.gimbal_rate_sp = np.zeros((1, n))
        self.rotor_speed_sp = np.full((1, n), params.nominal_rotor_speed)
        self.angle_target: Array | None = None
        self.rotor_undriven: Array | None = None
        self._drive: Drive | None = None  # drive() of the setpoints held now, built on demand
        self._inertias = [*self.gimbal_inertia.tolist(), *self.spin_inertia.tolist()]  # the drive's rows
        sv, lim = self.servo, params.limits
        self._header = (
            sv.load_rejection,
            sv.gimbal_time_constant_s,
            sv.rotor_time_constant_s,
            0.0 if sv.coast_time_constant_s is None else sv.coast_time_constant_s,
            lim.max_gimbal_torque,
            lim.max_rotor_torque,
            sv.angle_time_constant_s,
            lim.max_gimbal_rate,
        )

    def hold(
        self,
        setpoints: Setpoints,
        angle_target: ArrayLike | None = None,
        rotor_undriven: ArrayLike | None = None,
    ) -> None:
        """Take new setpoints (held until the next call). ``angle_target`` (B, n) rad: NaN where a gimbal
        follows its rate setpoint, else the angle its servo turns it to; ``rotor_undriven`` (B, n) bool:
        rotors that get no drive and keep their speed. None: every gimbal on its rate, every rotor driven."""
        self.gimbal_rate_sp = setpoints.gimbal_rate
        self.rotor_speed_sp = setpoints.rotor_speed
        self.angle_target = None if angle_target is None else np.asarray(angle_target, dtype=float)
        self.rotor_undriven = None if rotor_undriven is None else np.asarray(rotor_undriven, dtype=bool)
        self._drive = None

    def __call__(
        self,
        t: float,
        gimbal_angle: Array,
        gimbal_rate: Array,
        rotor_rate: Array,
        gimbal_load: Array,
        rotor_load: Array,
    ) -> tuple[Array, Array]:
        lim, sv = self.params.limits, self.servo
        rho = sv.load_rejection
        rate_sp = self.gimbal_rate_sp
        if self.angle_target is not None:
            on_angle = ~np.isnan(self.angle_target)
            err = np.where(on_angle, self.angle_target, 0.0) - gimbal_angle
            err = (err - _TWO_PI * np.rint(err / _TWO_PI)) / sv.angle_time_constant_s
            loop = np.clip(err, -lim.max_gimbal_rate, lim.max_gimbal_rate)
            rate_sp = np.where(on_angle, loop, rate_sp)
        ug = self.gimbal_inertia * (rate_sp - gimbal_rate) / sv.gimbal_time_constant_s
        err = self.rotor_speed_sp - rotor_rate
        tau = np.full_like(err, sv.rotor_time_constant_s)
        if sv.coast_time_constant_s is not None:
            tau = np.where(err < 0.0, sv.coast_time_constant_s, tau)
        us = np.clip(
            self.spin_inertia * err / tau - rho * rotor_load, -lim.max_rotor_torque, lim.max_rotor_torque
        )
        if self.rotor_undriven is not None:
            # no motor torque: drag alone slows the rotor (or nothing, without a coasting model)
            if sv.coast_time_constant_s is None:
                drag = np.zeros_like(rotor_rate)
            else:
                drag = -self.spin_inertia * rotor_rate / sv.coast_time_constant_s
            us = np.where(self.rotor_undriven, drag, us)
        return np.clip(ug - rho * gimbal_load, -lim.max_gimbal_torque, lim.max_gimbal_torque), us

    # ------------------------------------------------------------------ for the compiled plant
    def drive(self) -> Drive:
        """The held setpoints of a single run with this servo's parameters, as the compiled plant's
        :class:`.drives.Drive` (ConfigError if the setpoints are not one run's). Built once per
        :meth:`hold`."""
        if self._drive is None:
            self._drive = self._pack()
        return self._drive

    def _pack(self) -> Drive:
        """The held setpoints as a :class:`Drive` (:meth:`Drive.servo`'s layout), its data built from
        Python floats in one array: a world holds new setpoints at every pulse frame, where a dozen small
        numpy calls (NaN mask, where, six conversions, a concatenation) were most of the pack's ~10 µs."""
        n = len(self.spin_inertia)
        try:
            gimbal = _one_run(self.gimbal_rate_sp, n).tolist()
            rotor = _one_run(self.rotor_speed_sp, n).tolist()
            target = [math.nan] * n if self.angle_target is None else _one_run(self.angle_target, n).tolist()
            undriven = [0.0] * n if self.rotor_undriven is None else _one_run(self.rotor_undriven, n).tolist()
        except ValueError as e:
            raise ConfigError(f"the held setpoints are not one run's: {e}", "ServoModel.drive") from e
        on_angle = [not math.isnan(a) for a in target]
        setpoint = [a if on else g for a, on, g in zip(target, on_angle, gimbal, strict=True)]
        data = [*self._header, *self._inertias, *setpoint, *on_angle, *rotor, *undriven]
        return Drive(SERVO, np.array(data, dtype=float))


def _one_run(values: ArrayLike, n: int) -> Array:
    """``values`` broadcast to one run's row (n,) (ValueError if they are not one run's). A (1, n) array,
    what the world holds every pulse frame, is taken as it is: np.broadcast_to costs ~4 µs a call."""
    a = np.asarray(values)
    return a[0] if a.shape == (1, n) else np.broadcast_to(a, (1, n))[0]
