"""Sans-IO wire protocol of vscmg-hil: bytes in, events out. No serial ports, sockets, threads or clocks.

Both ends of the link (the host in ``hil``, the emulated board in ``firmware_sim``, and the C firmware)
speak it; ``docs/protocol.md`` is its byte-level specification.
"""

from .errors import FieldRangeError, FrameError, HilError, ProtocolError
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

__all__ = [name for name in dir() if not name.startswith("_")]
