"""One VSCMG unit's calibration set: rotor ESC and gimbal driver maps, immutable and hashable.

This is the object both ends share: the host converts with it for display and checks, the board (emulated
or real) converts setpoints to pulses with it, and ``to_bytes`` is what a ``CALIBRATION`` transfer carries.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..messages import GimbalMode
from .codec import decode_maps, encode_maps
from .conversion import Conversion
from .maps import GimbalAngleMap, GimbalRateMap, RotorSpeedMap


@dataclass(frozen=True, slots=True)
class UnitCalibration:
    """Rotor: pulse µs + battery V ↔ steady no-load speed rad/s. Gimbal: pulse µs ↔ rate rad/s (RATE
    mode) or angle rad (ANGLE mode). Every conversion clamps out-of-range inputs and says so."""

    rotor: RotorSpeedMap
    gimbal_rate: GimbalRateMap
    gimbal_angle: GimbalAngleMap

    # ------------------------------------------------------------------ rotor
    def rotor_pulse_us(self, speed_rad_s: float, battery_v: float) -> Conversion:
        """Setpoint → pulse: the pulse (µs) that makes the rotor settle at ``speed_rad_s`` (no load) at
        ``battery_v``. 0 rad/s is the minimum-throttle (arming) pulse; beyond full speed it saturates."""
        return self.rotor.pulse(speed_rad_s, battery_v)

    def rotor_speed(self, pulse_us: float, battery_v: float) -> Conversion:
        """Pulse → steady no-load rotor speed (rad/s) at ``battery_v``."""
        return self.rotor.speed(pulse_us, battery_v)

    # ------------------------------------------------------------------ gimbal
    def gimbal_pulse_us(self, value: float, mode: GimbalMode) -> Conversion:
        """Setpoint → pulse: ``value`` is a rate (rad/s) in RATE mode, an angle (rad) in ANGLE mode.
        Rate 0 is the hold pulse."""
        if mode == GimbalMode.RATE:
            return self.gimbal_rate.pulse(value)
        return self.gimbal_angle.pulse(value)

    def gimbal_value(self, pulse_us: float, mode: GimbalMode) -> Conversion:
        """Pulse → the rate (rad/s, RATE mode) or angle (rad, ANGLE mode) it stands for."""
        if mode == GimbalMode.RATE:
            return self.gimbal_rate.rate(pulse_us)
        return self.gimbal_angle.angle(pulse_us)

    # ------------------------------------------------------------------ binary form
    def to_bytes(self) -> bytes:
        """The version-1 binary set (``docs/calibration.md``)."""
        return encode_maps(self.rotor, self.gimbal_rate, self.gimbal_angle)

    @classmethod
    def from_bytes(cls, data: bytes, source: str = "") -> UnitCalibration:
        """Parse a binary set; :class:`~protocol.errors.CalibrationError` naming ``source`` and the field
        for anything malformed."""
        return cls(*decode_maps(data, source))
