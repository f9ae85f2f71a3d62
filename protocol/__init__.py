"""Sans-IO wire protocol of vscmg-hil: bytes in, events out. No serial ports, sockets, threads or clocks.

Both ends of the link (the host in ``hil``, the emulated board in ``firmware_sim``, and the C firmware)
speak it; ``docs/protocol.md`` is its byte-level specification.
"""

from .errors import CommandFailed, FieldRangeError, FrameError, HilError, ProtocolError
from .frame import BadFrame, BadFrameReason, Deframer, Frame, Framer, LinkCounters, decode_frame, encode_frame
from .messages import (
    BY_ID,
    CATALOGUE,
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    CalibrationData,
    CalibrationRequest,
    ControlMode,
    Disarm,
    EscCalAbort,
    EscCalibrate,
    EscCalibrationStatus,
    EscCalPhase,
    EscCalStep,
    FaultFlag,
    Flags,
    GimbalMode,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    Nack,
    NackReason,
    PowerState,
    RawPulses,
    ResetCause,
    SetMode,
    Severity,
    Telemetry,
    UnitSetpoint,
    UnitState,
    WatchdogState,
)
from .reliable import AnswerCache, Command, CommandState, ReliableSender, RetryPolicy

__all__ = [
    "accessory_interfaces",
    "AccessoryIdentity",
    "Ack",
    "ActuatorSetpoint",
    "AnswerCache",
    "Arm",
    "BadFrame",
    "BadFrameReason",
    "BoardState",
    "BY_ID",
    "CalibrationData",
    "CalibrationRequest",
    "CanFrame",
    "CanReassembler",
    "CanSegmenter",
    "CATALOGUE",
    "Command",
    "CommandFailed",
    "CommandState",
    "ControlMode",
    "ControlTransfer",
    "decode_frame",
    "Deframer",
    "Disarm",
    "encode_frame",
    "EscCalAbort",
    "EscCalibrate",
    "EscCalibrationStatus",
    "EscCalPhase",
    "EscCalStep",
    "FaultFlag",
    "FieldRangeError",
    "Flags",
    "Frame",
    "FrameError",
    "Framer",
    "GimbalMode",
    "Heartbeat",
    "Hello",
    "HelloReply",
    "HilError",
    "is_accessory_mode",
    "LinkCounters",
    "Log",
    "Nack",
    "NackReason",
    "PowerState",
    "PROTOCOL_VERSION",
    "ProtocolError",
    "RawPulses",
    "ReliableSender",
    "ResetCause",
    "RetryPolicy",
    "SCHEMA_HASH",
    "SetMode",
    "Severity",
    "start_sequence",
    "Telemetry",
    "UnitSetpoint",
    "UnitState",
    "WatchdogState",
]

_LAZY = {
    "AccessoryIdentity": "aoa",
    "ControlTransfer": "aoa",
    "accessory_interfaces": "aoa",
    "is_accessory_mode": "aoa",
    "start_sequence": "aoa",
    "CanFrame": "can",
    "CanReassembler": "can",
    "CanSegmenter": "can",
}
"""Names of the USB (AOA) and CAN transports' framing, imported on first use: a run over a serial link or
the built-in emulator (most of them) needs neither module, and importing both cost ~10 ms of every
``hil run``'s start (issue 29: the imports before its first tick)."""


def __getattr__(name: str) -> object:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
