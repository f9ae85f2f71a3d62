"""Motor-level loops, host side. Pure math.

:class:`SetpointGenerator` turns steering's commands (gimbal rates, rotor accelerations) into
what the board takes, an ``ActuatorSetpoint`` per control period: a gimbal rate (RATE mode, rad/s) and a
rotor *speed* (rad/s). The speed setpoint integrates the commanded acceleration, with anti-windup: it is
clamped to the rotor speed range and never runs more than ``max_lead`` rad/s ahead of (or behind) the
measured speed, so an ESC that lags or saturates does not wind the setpoint up. The control rate may not
exceed the board's pulse frame rate (a faster loop would only have its setpoints dropped).

:class:`ServoParams` are the motor drivers' response as a scenario states it; what the drivers do with the
setpoints, as torques on the plant, is the world's (:class:`firmware_sim.world.models.servos.ServoModel`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.control.steering import SteeringOutput
from hil.vscmg import SpacecraftParams
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
        rates, speeds = self.gimbal_rate[index].tolist(), self.rotor_speed[index].tolist()
        units = tuple(map(UnitSetpoint, rates, speeds))  # (gimbal, rotor_speed): Python floats
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
        if not (math.isfinite(frame_rate_hz) and frame_rate_hz > 0):  # NaN once passed the check below
            raise ConfigError(f"must be positive, got {frame_rate_hz!r}", "SetpointGenerator.frame_rate_hz")
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
        measured = np.array(measured_rotor_speed, dtype=float, ndmin=2, copy=None)  # (B, n), not copied
        if self.rotor_speed is None:
            self.reset(measured)
        assert self.rotor_speed is not None
        if measured.shape[0] == 1 and self.rotor_speed.shape[0] == 1 and command.rotor_accel.shape[0] == 1:
            return self._update_one(command, measured)
        wanted = self.rotor_speed + command.rotor_accel * self.dt
        lo = np.maximum(lim.min_rotor_speed, measured - self.max_lead)
        hi = np.minimum(lim.max_rotor_speed, measured + self.max_lead)
        # clamps as minimum(maximum(..)), which np.clip is defined as, without its dispatch (once per tick)
        speed = np.minimum(np.maximum(wanted, lo), hi)
        rate = np.minimum(np.maximum(command.gimbal_rate, -lim.max_gimbal_rate), lim.max_gimbal_rate)
        clamped = ((speed != wanted) | (rate != command.gimbal_rate)).any(axis=1)
        self.rotor_speed = speed
        return Setpoints(rate, speed.copy(), clamped)

    def _update_one(self, command: SteeringOutput, measured: Array) -> Setpoints:
        """:meth:`update` for one run (B = 1, the control tick's case) on Python floats
        (:meth:`update_floats`), without ~10 numpy calls on (1, n) arrays (~50 µs a tick against ~10)."""
        speeds, rates, clamped = self.update_floats(
            command.gimbal_rate[0].tolist(), command.rotor_accel[0].tolist(), measured[0].tolist()
        )
        return Setpoints(np.array([rates]), np.array([speeds]), np.array([clamped]))

    def update_floats(
        self, gimbal_rate: Sequence[float], rotor_accel: Sequence[float], measured: Sequence[float]
    ) -> tuple[list[float], list[float], bool]:
        """:meth:`update` for one run on Python floats: steering's ``gimbal_rate`` (rad/s) and
        ``rotor_accel`` (rad/s²) and the ``measured`` rotor speeds (rad/s), n each. Returns the speed
        setpoints (rad/s), the gimbal-rate setpoints (rad/s) and whether a limit cut a command. The same
        IEEE operations and numpy's ``maximum``/``minimum`` semantics (:func:`_maximum`, :func:`_minimum`:
        NaN propagates, a tie gives the second, ±0 included), so the same bits as :meth:`update`."""
        if self.rotor_speed is None:
            self.reset([list(measured)])
        assert self.rotor_speed is not None
        if self.rotor_speed.shape[0] != 1:
            raise ValueError(f"update_floats is for one run; the generator holds {self.rotor_speed.shape[0]}")
        lim = self.params.limits
        dt, lead = self.dt, self.max_lead
        lo_limit, hi_limit, rate_limit = lim.min_rotor_speed, lim.max_rotor_speed, lim.max_gimbal_rate
        speeds: list[float] = []
        rates: list[float] = []
        clamped = False
        for held, accel, now, asked in zip(
            self.rotor_speed[0].tolist(), rotor_accel, measured, gimbal_rate, strict=True
        ):
            wanted = held + accel * dt
            lo = _maximum(lo_limit, now - lead)
            hi = _minimum(hi_limit, now + lead)
            speed = _minimum(_maximum(wanted, lo), hi)
            rate = _minimum(_maximum(asked, -rate_limit), rate_limit)
            clamped = clamped or speed != wanted or rate != asked
            speeds.append(speed)
            rates.append(rate)
        self.rotor_speed = np.array([speeds])
        return speeds, rates, clamped


def _maximum(a: float, b: float) -> float:
    """``np.maximum(a, b)`` on two floats: NaN if either is, ``b`` on a tie (as numpy, ±0 included)."""
    return a if a > b or a != a else b


def _minimum(a: float, b: float) -> float:
    """``np.minimum(a, b)`` on two floats: NaN if either is, ``b`` on a tie (as numpy, ±0 included)."""
    return a if a < b or a != a else b


@dataclass(frozen=True)
class ServoParams:
    """Motor-driver response: ``gimbal_time_constant_s``, ``rotor_time_constant_s`` (spinning up and, with
    an ESC that brakes, down), ``coast_time_constant_s`` (None: the ESC brakes; else slowing down follows
    this), ``load_rejection`` ρ in [0, 1] (how much of the gyroscopic load the drives cancel),
    ``angle_time_constant_s`` the gimbal servo's position loop (a gimbal driven to an angle, ANGLE mode)."""

    gimbal_time_constant_s: float = 0.05
    rotor_time_constant_s: float = 0.15
    coast_time_constant_s: float | None = None
    load_rejection: float = 1.0
    angle_time_constant_s: float = 0.1

    def __post_init__(self) -> None:
        for name in (
            "gimbal_time_constant_s",
            "rotor_time_constant_s",
            "coast_time_constant_s",
            "angle_time_constant_s",
        ):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ConfigError(f"must be positive, got {v!r}", f"ServoParams.{name}")
        if not 0.0 <= self.load_rejection <= 1.0:
            raise ConfigError(
                f"must lie in [0, 1], got {self.load_rejection!r}", "ServoParams.load_rejection"
            )
