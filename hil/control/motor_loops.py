"""Motor-level loops on both sides of the wire. Pure math.

Host side, :class:`SetpointGenerator`: turns steering's commands (gimbal rates, rotor accelerations) into
what the board takes, an ``ActuatorSetpoint`` per control period: a gimbal rate (RATE mode, rad/s) and a
rotor *speed* (rad/s). The speed setpoint integrates the commanded acceleration, with anti-windup: it is
clamped to the rotor speed range and never runs more than ``max_lead`` rad/s ahead of (or behind) the
measured speed, so an ESC that lags or saturates does not wind the setpoint up. The control rate may not
exceed the board's pulse frame rate (a faster loop would only have its setpoints dropped).

Plant side, :class:`ServoModel`: what the motor drivers do with those setpoints, as torques on the
plant (:data:`hil.vscmg.TorqueLaw`), so a simulated world closes the loop board pulses → motor torque →
plant. Unloaded, both respond in first order with the time constants of ``firmware_sim.actuators``
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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.control.steering import SteeringOutput
from hil.vscmg import SpacecraftParams
from hil.vscmg.params import inertia_tensor
from protocol.errors import ConfigError
from protocol.messages import ActuatorSetpoint, GimbalMode, UnitSetpoint

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Setpoints:
    """One control period's setpoints, batch B: ``gimbal_rate`` (B, n) rad/s, ``rotor_speed`` (B, n) rad/s;
    ``clamped`` (B,) true where a limit or the anti-windup cut a command."""

    gimbal_rate: Array
    rotor_speed: Array
    clamped: Array

    def message(self, index: int = 0) -> ActuatorSetpoint:
        """Run ``index``'s setpoints as the wire message (RATE mode)."""
        units = tuple(
            UnitSetpoint(gimbal=float(g), rotor_speed=float(w))
            for g, w in zip(self.gimbal_rate[index], self.rotor_speed[index], strict=True)
        )
        return ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=units)


class SetpointGenerator:
    """Steering output → board setpoints at ``control_rate_hz`` (≤ ``frame_rate_hz``, the board's pulse
    frame rate). ``max_lead`` rad/s bounds how far the speed setpoint may run from the measured speed."""

    def __init__(
        self,
        params: SpacecraftParams,
        control_rate_hz: float,
        frame_rate_hz: float = 50.0,
        max_lead: float = 50.0,
    ) -> None:
        if not (math.isfinite(control_rate_hz) and control_rate_hz > 0):
            raise ConfigError(
                f"must be positive, got {control_rate_hz!r}", "SetpointGenerator.control_rate_hz"
            )
        if control_rate_hz > frame_rate_hz * (1 + 1e-9):
            raise ConfigError(
                f"{control_rate_hz} Hz is faster than the pulse frame rate {frame_rate_hz} Hz",
                "SetpointGenerator.control_rate_hz",
            )
        if not max_lead > 0:
            raise ConfigError("must be positive", "SetpointGenerator.max_lead")
        self.params = params
        self.dt = 1.0 / control_rate_hz
        self.max_lead = max_lead
        self.rotor_speed: Array | None = None

    def reset(self, rotor_speed: ArrayLike) -> None:
        """Start the speed setpoints at ``rotor_speed`` (B, n) rad/s (e.g. the measured speeds)."""
        self.rotor_speed = np.atleast_2d(np.asarray(rotor_speed, dtype=float)).copy()

    def update(self, command: SteeringOutput, measured_rotor_speed: ArrayLike) -> Setpoints:
        """One control period: integrate the rotor accelerations over the period, clamp, anti-windup."""
        lim = self.params.limits
        measured = np.atleast_2d(np.asarray(measured_rotor_speed, dtype=float))
        if self.rotor_speed is None:
            self.reset(measured)
        assert self.rotor_speed is not None
        wanted = self.rotor_speed + command.rotor_accel * self.dt
        lo = np.maximum(lim.min_rotor_speed, measured - self.max_lead)
        hi = np.minimum(lim.max_rotor_speed, measured + self.max_lead)
        speed = np.clip(wanted, lo, hi)
        rate = np.clip(command.gimbal_rate, -lim.max_gimbal_rate, lim.max_gimbal_rate)
        clamped = np.any((speed != wanted) | (rate != command.gimbal_rate), axis=1)
        self.rotor_speed = speed
        return Setpoints(rate, speed.copy(), clamped)


@dataclass(frozen=True)
class ServoParams:
    """Motor-driver response: ``gimbal_time_constant_s``, ``rotor_time_constant_s`` (spinning up and, with
    an ESC that brakes, down), ``coast_time_constant_s`` (None: the ESC brakes; else slowing down follows
    this), ``load_rejection`` ρ in [0, 1] (how much of the gyroscopic load the drives cancel)."""

    gimbal_time_constant_s: float = 0.05
    rotor_time_constant_s: float = 0.15
    coast_time_constant_s: float | None = None
    load_rejection: float = 1.0

    def __post_init__(self) -> None:
        for name in ("gimbal_time_constant_s", "rotor_time_constant_s", "coast_time_constant_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ConfigError(f"must be positive, got {v!r}", f"ServoParams.{name}")
        if not 0.0 <= self.load_rejection <= 1.0:
            raise ConfigError(
                f"must lie in [0, 1], got {self.load_rejection!r}", "ServoParams.load_rejection"
            )


class ServoModel:
    """Gimbal and rotor servos of every unit as a :data:`hil.vscmg.TorqueLaw`: call :meth:`hold` with the
    current setpoints and pass the instance to ``Plant.step``."""

    def __init__(self, params: SpacecraftParams, servo: ServoParams | None = None) -> None:
        self.params = params
        self.servo = servo or ServoParams()
        units = params.units
        ig = [inertia_tensor(u.gimbal_inertia, "gimbal_inertia")[2, 2] for u in units]
        iw = [inertia_tensor(u.rotor_inertia, "rotor_inertia")[2, 2] for u in units]
        self.gimbal_inertia = np.array(ig) + np.array(iw)
        self.spin_inertia = np.array([u.rotor_spin_inertia for u in units])
        self.gimbal_rate_sp = np.zeros((1, len(units)))
        self.rotor_speed_sp = np.full((1, len(units)), params.nominal_rotor_speed)
        self._scalar_src: tuple[Array, Array] | None = None
        self._scalar_inertia: list[tuple[float, float]] = []

    def hold(self, setpoints: Setpoints) -> None:
        """Take new setpoints (held until the next call)."""
        self.gimbal_rate_sp = setpoints.gimbal_rate
        self.rotor_speed_sp = setpoints.rotor_speed

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
        ug = self.gimbal_inertia * (self.gimbal_rate_sp - gimbal_rate) / sv.gimbal_time_constant_s
        err = self.rotor_speed_sp - rotor_rate
        tau = np.full_like(err, sv.rotor_time_constant_s)
        if sv.coast_time_constant_s is not None:
            tau = np.where(err < 0.0, sv.coast_time_constant_s, tau)
        us = self.spin_inertia * err / tau
        return (
            np.clip(ug - rho * gimbal_load, -lim.max_gimbal_torque, lim.max_gimbal_torque),
            np.clip(us - rho * rotor_load, -lim.max_rotor_torque, lim.max_rotor_torque),
        )

    # ------------------------------------------------------------------ one run in floats
    def scalar_setpoints(self) -> tuple[list[float], list[float]]:
        """The held setpoints of a single run as floats ``(gimbal rates, rotor speeds)``, for
        :meth:`torques_scalar` (:class:`hil.vscmg.fast.SingleRunPlant` reads them once per step)."""
        n = len(self.spin_inertia)
        out = []
        for sp in (self.gimbal_rate_sp, self.rotor_speed_sp):
            if not (isinstance(sp, np.ndarray) and sp.shape == (1, n)):  # the usual shape, else broadcast
                try:
                    sp = np.broadcast_to(np.asarray(sp, dtype=float), (1, n))
                except ValueError as e:
                    raise ConfigError(
                        f"the held setpoints are not one run's: {e}", "ServoModel.scalar_setpoints"
                    ) from e
            out.append(sp[0].tolist())
        return out[0], out[1]

    def torques_scalar(
        self,
        gimbal_rate: Sequence[float],
        rotor_rate: Sequence[float],
        gimbal_load: Sequence[float],
        rotor_load: Sequence[float],
        setpoints: tuple[Sequence[float], Sequence[float]] | None = None,
    ) -> tuple[list[float], list[float]]:
        """What :meth:`__call__` gives for one run, on sequences of n floats: ``(gimbal torques, rotor
        torques)``. ``setpoints``: :meth:`scalar_setpoints` read beforehand (default: read now)."""
        gsp, wsp = self.scalar_setpoints() if setpoints is None else setpoints
        src = self._scalar_src
        if src is None or src[0] is not self.gimbal_inertia or src[1] is not self.spin_inertia:
            self._scalar_src = (self.gimbal_inertia, self.spin_inertia)
            self._scalar_inertia = list(
                zip(self.gimbal_inertia.tolist(), self.spin_inertia.tolist(), strict=True)
            )
        lim, sv = self.params.limits, self.servo
        rho, tg, tr, tc = (
            sv.load_rejection,
            sv.gimbal_time_constant_s,
            sv.rotor_time_constant_s,
            sv.coast_time_constant_s,
        )
        gmax, rmax = lim.max_gimbal_torque, lim.max_rotor_torque
        ug: list[float] = []
        us: list[float] = []
        for (jg, js), gs, ws, gr, wr, fg, fp in zip(
            self._scalar_inertia, gsp, wsp, gimbal_rate, rotor_rate, gimbal_load, rotor_load, strict=True
        ):
            u = jg * (gs - gr) / tg - rho * fg
            # np.clip(u, lo, hi) = min(max(u, lo), hi), NaN passing through
            ug.append(-gmax if u < -gmax else gmax if u > gmax else u)
            err = ws - wr
            u = js * err / (tc if tc is not None and err < 0.0 else tr) - rho * fp
            us.append(-rmax if u < -rmax else rmax if u > rmax else u)
        return ug, us
