"""ESC and gimbal calibration maps, their binary form, and their transfer over the link. Sans-IO.

``UnitCalibration`` is one VSCMG unit's set (rotor ESC + gimbal driver maps, each with its inverse);
``docs/calibration.md`` specifies the maps' evaluation and the binary format byte by byte.
Modules: ``conversion`` (the result type), ``cubic`` (the monotone table every map is built from),
``maps`` (ESC/rotor/gimbal maps), ``unit`` (the set), ``codec`` (bytes), ``transfer`` (fragments),
``model`` (the stated actuator models and the default set).
"""

from .codec import FORMAT_VERSION, MAX_SIZE, MIN_SIZE
from .conversion import Clamp, Conversion
from .cubic import MAX_KNOTS, MonotoneCubic, pchip_slopes
from .maps import MIN_SUPPLY_V, EscThrottleMap, GimbalAngleMap, GimbalRateMap, RotorSpeedMap
from .model import EscMotorModel, GimbalServoModel, default_unit_calibration, model_unit_calibration
from .transfer import MAX_TRANSFER_BYTES, Reassembler, ReassemblyCounters, fragment, reassemble
from .unit import UnitCalibration

__all__ = [
    "FORMAT_VERSION",
    "MAX_KNOTS",
    "MAX_SIZE",
    "MAX_TRANSFER_BYTES",
    "MIN_SIZE",
    "MIN_SUPPLY_V",
    "Clamp",
    "Conversion",
    "EscMotorModel",
    "EscThrottleMap",
    "GimbalAngleMap",
    "GimbalRateMap",
    "GimbalServoModel",
    "MonotoneCubic",
    "Reassembler",
    "ReassemblyCounters",
    "RotorSpeedMap",
    "UnitCalibration",
    "default_unit_calibration",
    "fragment",
    "model_unit_calibration",
    "pchip_slopes",
    "reassemble",
]
