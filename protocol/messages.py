"""The message catalogue: one frozen dataclass per message, with its wire id, fields, units and ranges.

``docs/protocol.md`` is the byte-level specification of these classes; ``fixtures/protocol_vectors.json``
holds canonical frames for every one. Field order is wire order. Directions: H→B host to board, B→H board
to host. Messages marked *reliable* are sent with the ``ACK_REQUESTED`` flag and answered by ``Ack`` or
``Nack`` with the same sequence number (see :mod:`protocol.reliable`).
"""

from __future__ import annotations

import enum
import hashlib
import struct
from dataclasses import dataclass
from typing import Any, ClassVar

from .compiled import CodecTable
from .fields import F32, U8, U16, U32, Array, Blob, Enum8, Layout, Text, layout_of, wire

PROTOCOL_VERSION = 1
MAX_UNITS = 8
MAX_CHANNELS = 2 * MAX_UNITS
MAX_CALIBRATION_CHUNK = 200

# Ranges of the physical quantities on the wire (SI units).
GIMBAL_RATE_LIMIT = 20.0  # rad/s, |gimbal rate|
GIMBAL_ANGLE_LIMIT = 100.0  # rad, |gimbal angle| (multi-turn gimbals are allowed)
ROTOR_SPEED_LIMIT = 2500.0  # rad/s, |rotor speed| (~23,900 rpm)
PULSE_MIN_US = 500
PULSE_MAX_US = 2500


# --------------------------------------------------------------------------- enumerations
class BoardState(enum.IntEnum):
    """The board's state machine (see docs/protocol.md, "Board states")."""

    BOOT = 0
    DISARMED = 1
    ARMED = 2
    FAILSAFE = 3


class ResetCause(enum.IntEnum):
    """Why the board last reset (from the MCU's reset-cause register)."""

    POWER_ON = 0
    WATCHDOG = 1
    BROWN_OUT = 2
    EXTERNAL = 3
    SOFTWARE = 4


class ControlMode(enum.IntEnum):
    """What the board does with setpoints (``SetMode``)."""

    SETPOINT = 0  # ActuatorSetpoint through the calibration maps
    RAW_PULSES = 1  # RawPulses passed through as pulse widths
    ESC_CALIBRATION = 2  # the ESC high/low endpoint procedure runs (entered only by EscCalibrate)


class GimbalMode(enum.IntEnum):
    """How ``UnitSetpoint.gimbal`` is interpreted."""

    RATE = 0  # rad/s
    ANGLE = 1  # rad


class NackReason(enum.IntEnum):
    BAD_STATE = 1  # not allowed in the board's current state
    OUT_OF_RANGE = 2  # a value the board cannot honour
    UNSUPPORTED = 3  # message or mode not implemented by this board
    BUSY = 4  # a transfer is already in progress
    BAD_CALIBRATION = 5  # calibration data failed its CRC or validation
    POWER = 6  # refused because of the power state (load shed)
    UNCONFIRMED = 7  # a guarded command without its explicit confirmation (EscCalibrate.confirm)


class EscCalStep(enum.IntEnum):
    """What an ``EscCalibrate`` command asks for."""

    START = 0  # start the procedure on ``unit``'s rotor channel
    SUPPLY_APPLIED = 1  # the operator has connected the ESC's supply (boards without a supply switch)


class EscCalPhase(enum.IntEnum):
    """Where the board's ESC endpoint procedure is (``EscCalibrationStatus.phase``)."""

    IDLE = 0  # no procedure
    SUPPLY_OFF = 1  # the board has cut the ESCs' supply; the channel is set to the high endpoint
    WAIT_SUPPLY = 2  # high endpoint on the channel; waiting for the operator to connect the ESC supply
    HIGH = 3  # the ESC is powered and sees the high endpoint: its acknowledgement interval
    LOW = 4  # the channel is at the low endpoint: the ESC stores both
    DONE = 5  # finished: the channel is back at the safe pulse
    ABORTED = 6  # stopped early (``abort`` says why): the channel is at the safe (minimum) pulse


class EscCalAbort(enum.IntEnum):
    """Why an ESC endpoint procedure stopped early."""

    NONE = 0
    DISARM = 1  # a Disarm
    LINK_LOST = 2  # the link watchdog expired
    HELLO = 3  # a new session (Hello)
    POWER = 4  # the power manager shed load
    SUPPLY_TIMEOUT = 5  # nobody confirmed the ESC's supply in time


ESC_CALIBRATION_CONFIRM = 0x444C4E55
"""``EscCalibrate.confirm`` must be this (the bytes of ASCII "UNLD" on the wire): the operator states the
rotor is off or unloaded, because the ESC sees its full-throttle pulse during the procedure."""

ESC_SUPPLY_WAIT_MS = 60_000
"""A board without an ESC supply switch holds the procedure at ``WAIT_SUPPLY`` this long (ms) for the
operator to connect the ESC's supply (while its link lives: link loss aborts it), then aborts it
``SUPPLY_TIMEOUT``."""


class PowerState(enum.IntEnum):
    """Staged power thresholds: warn → limit → shed (rotors stopped) → brown-out (reset)."""

    NORMAL = 0
    WARN = 1
    LIMIT = 2
    SHED = 3
    BROWN_OUT = 4


class WatchdogState(enum.IntEnum):
    OK = 0
    LINK_LOST = 1  # link watchdog expired: failsafe outputs


class Severity(enum.IntEnum):
    DEBUG = 0
    INFO = 1
    WARNING = 2
    ERROR = 3
    CRITICAL = 4


class FaultFlag(enum.IntFlag):
    """Bits of ``Telemetry.faults``."""

    NONE = 0
    LINK_LOST = 0x0001
    DEAD_ESC = 0x0002
    BATTERY_LOW = 0x0004
    UBEC_OVERCURRENT = 0x0008
    CALIBRATION_MISSING = 0x0010
    MCU_WATCHDOG_RESET = 0x0020
    BROWN_OUT_RESET = 0x0040
    SETPOINT_CLAMPED = 0x0080


class Flags(enum.IntFlag):
    """Bits of the frame header's flags byte."""

    NONE = 0
    ACK_REQUESTED = 0x01  # reliable command: answer with Ack/Nack carrying this sequence number
    RETRANSMIT = 0x02  # a retry of an earlier frame with the same sequence number


# --------------------------------------------------------------------------- records
@dataclass(frozen=True, slots=True)
class UnitSetpoint:
    """One VSCMG unit's command."""

    gimbal: float = wire(F32(-GIMBAL_ANGLE_LIMIT, GIMBAL_ANGLE_LIMIT, "rad/s or rad"), 0.0)
    rotor_speed: float = wire(F32(-ROTOR_SPEED_LIMIT, ROTOR_SPEED_LIMIT, "rad/s"), 0.0)


@dataclass(frozen=True, slots=True)
class UnitState:
    """One VSCMG unit's measured (or emulated) state."""

    gimbal_angle: float = wire(F32(-GIMBAL_ANGLE_LIMIT, GIMBAL_ANGLE_LIMIT, "rad"), 0.0)
    gimbal_rate: float = wire(F32(-GIMBAL_RATE_LIMIT, GIMBAL_RATE_LIMIT, "rad/s"), 0.0)
    rotor_speed: float = wire(F32(-ROTOR_SPEED_LIMIT, ROTOR_SPEED_LIMIT, "rad/s"), 0.0)


# --------------------------------------------------------------------------- messages
class Message:
    """Base of all messages: ``MSG_ID`` is the wire id, ``RELIABLE`` says it is acknowledged.
    ``SETS`` names what a reliable command sets on the board (``"arming"``, ``"mode"``), when a later
    command setting the same thing makes its retries wrong: the latest wins
    (:class:`~protocol.reliable.ReliableSender` stops retrying the older one)."""

    MSG_ID: ClassVar[int]
    RELIABLE: ClassVar[bool] = False
    SETS: ClassVar[str | None] = None


_IDENTITY_DOC = "AOA accessory identity string"
_BOOT_ID_DOC = "drawn anew at every boot of the board; 0: the board does not say"


@dataclass(frozen=True, slots=True)
class Hello(Message):
    """H→B, reliable in effect (answered by HelloReply, retried by the host). Starts a session."""

    MSG_ID: ClassVar[int] = 0x01
    protocol_version: int = wire(U8(1, 255), PROTOCOL_VERSION)
    schema_hash: int = wire(U32(), 0)
    manufacturer: str = wire(Text(24, _IDENTITY_DOC), "")
    model: str = wire(Text(24, _IDENTITY_DOC), "")
    description: str = wire(Text(48, _IDENTITY_DOC), "")
    version: str = wire(Text(16, _IDENTITY_DOC), "")
    uri: str = wire(Text(64, _IDENTITY_DOC), "")
    serial: str = wire(Text(24, _IDENTITY_DOC), "")


@dataclass(frozen=True, slots=True)
class HelloReply(Message):
    """B→H: the board's identity, its protocol version and schema hash, why it last reset and its boot id."""

    MSG_ID: ClassVar[int] = 0x02
    protocol_version: int = wire(U8(1, 255), PROTOCOL_VERSION)
    schema_hash: int = wire(U32(), 0)
    reset_cause: ResetCause = wire(Enum8(ResetCause), ResetCause.POWER_ON)
    state: BoardState = wire(Enum8(BoardState), BoardState.DISARMED)
    n_units: int = wire(U8(0, MAX_UNITS), 0)
    frame_rate_hz: int = wire(U16(0, 500, "Hz"), 50)
    boot_id: int = wire(U32(doc=_BOOT_ID_DOC), 0)
    manufacturer: str = wire(Text(24, _IDENTITY_DOC), "")
    model: str = wire(Text(24, _IDENTITY_DOC), "")
    description: str = wire(Text(48, _IDENTITY_DOC), "")
    version: str = wire(Text(16, _IDENTITY_DOC), "")
    uri: str = wire(Text(64, _IDENTITY_DOC), "")
    serial: str = wire(Text(24, _IDENTITY_DOC), "")
    firmware_build: str = wire(Text(24), "")


@dataclass(frozen=True, slots=True)
class Heartbeat(Message):
    """Both ways. ``state`` is the sender's state: a BoardState value from the board, 0 from the host;
    ``boot_id`` the board's boot id (as in its HelloReply), 0 from the host."""

    MSG_ID: ClassVar[int] = 0x03
    time_ms: int = wire(U32(unit="ms"), 0)
    state: int = wire(U8(), 0)
    boot_id: int = wire(U32(doc=_BOOT_ID_DOC), 0)


@dataclass(frozen=True, slots=True)
class Arm(Message):
    """H→B, reliable: DISARMED or FAILSAFE → ARMED."""

    MSG_ID: ClassVar[int] = 0x10
    RELIABLE: ClassVar[bool] = True
    SETS: ClassVar[str | None] = "arming"


@dataclass(frozen=True, slots=True)
class Disarm(Message):
    """H→B, reliable: → DISARMED (rotors to minimum throttle, gimbals hold)."""

    MSG_ID: ClassVar[int] = 0x11
    RELIABLE: ClassVar[bool] = True
    SETS: ClassVar[str | None] = "arming"


@dataclass(frozen=True, slots=True)
class SetMode(Message):
    """H→B, reliable: select how setpoints are turned into pulses."""

    MSG_ID: ClassVar[int] = 0x12
    RELIABLE: ClassVar[bool] = True
    SETS: ClassVar[str | None] = "mode"
    mode: ControlMode = wire(Enum8(ControlMode), ControlMode.SETPOINT)


@dataclass(frozen=True, slots=True)
class EscCalibrate(Message):
    """H→B, reliable, DISARMED only: teach unit ``unit``'s rotor ESC its endpoints (docs/protocol.md,
    "ESC endpoint programming"); ``confirm`` must be ESC_CALIBRATION_CONFIRM. The board times the steps."""

    MSG_ID: ClassVar[int] = 0x15
    RELIABLE: ClassVar[bool] = True
    unit: int = wire(U8(0, MAX_UNITS - 1), 0)
    step: EscCalStep = wire(Enum8(EscCalStep), EscCalStep.START)
    confirm: int = wire(U32(), 0)
    low_us: int = wire(U16(PULSE_MIN_US, PULSE_MAX_US, "us"), 1000)
    high_us: int = wire(U16(PULSE_MIN_US, PULSE_MAX_US, "us"), 2000)
    supply_off_ms: int = wire(U16(0, 10_000, "ms"), 1500)
    high_ms: int = wire(U16(100, 20_000, "ms"), 3000)
    low_ms: int = wire(U16(100, 20_000, "ms"), 2000)


@dataclass(frozen=True, slots=True)
class Ack(Message):
    """Either way: the reliable frame (``msg_id``, ``seq``) was accepted."""

    MSG_ID: ClassVar[int] = 0x13
    msg_id: int = wire(U8(), 0)
    seq: int = wire(U8(), 0)


@dataclass(frozen=True, slots=True)
class Nack(Message):
    """Either way: the reliable frame (``msg_id``, ``seq``) was refused, with a reason."""

    MSG_ID: ClassVar[int] = 0x14
    msg_id: int = wire(U8(), 0)
    seq: int = wire(U8(), 0)
    reason: NackReason = wire(Enum8(NackReason), NackReason.BAD_STATE)


@dataclass(frozen=True, slots=True)
class ActuatorSetpoint(Message):
    """H→B at the control rate, newest wins, never acknowledged. One entry per VSCMG unit."""

    MSG_ID: ClassVar[int] = 0x20
    gimbal_mode: GimbalMode = wire(Enum8(GimbalMode), GimbalMode.RATE)
    units: tuple[UnitSetpoint, ...] = wire(Array(UnitSetpoint, 1, MAX_UNITS), ())


@dataclass(frozen=True, slots=True)
class RawPulses(Message):
    """H→B in RAW_PULSES mode: pulse widths per output channel (gimbal 0, rotor 0, gimbal 1, ...)."""

    MSG_ID: ClassVar[int] = 0x21
    pulses_us: tuple[int, ...] = wire(Array(U16(PULSE_MIN_US, PULSE_MAX_US, "us"), 1, MAX_CHANNELS), ())


@dataclass(frozen=True, slots=True)
class CalibrationData(Message):
    """Either way, reliable: one fragment of a unit's serialised calibration set.

    A set of ``total_len`` bytes with CRC-16 ``set_crc`` is cut into ``count`` chunks of at most
    ``MAX_CALIBRATION_CHUNK`` bytes; ``transfer_id`` ties the fragments of one transfer together.
    """

    MSG_ID: ClassVar[int] = 0x30
    RELIABLE: ClassVar[bool] = True
    unit: int = wire(U8(0, MAX_UNITS - 1), 0)
    transfer_id: int = wire(U8(), 0)
    index: int = wire(U8(), 0)
    count: int = wire(U8(1, 255), 1)
    total_len: int = wire(U16(0, 255 * MAX_CALIBRATION_CHUNK, "bytes"), 0)
    set_crc: int = wire(U16(), 0)
    chunk: bytes = wire(Blob(MAX_CALIBRATION_CHUNK), b"")


@dataclass(frozen=True, slots=True)
class CalibrationRequest(Message):
    """H→B, reliable: ask the board to send unit ``unit``'s stored calibration set as CalibrationData."""

    MSG_ID: ClassVar[int] = 0x31
    RELIABLE: ClassVar[bool] = True
    unit: int = wire(U8(0, MAX_UNITS - 1), 0)
    transfer_id: int = wire(U8(), 0)


@dataclass(frozen=True, slots=True)
class Telemetry(Message):
    """B→H at the telemetry rate: board state, power, outputs and link counters."""

    MSG_ID: ClassVar[int] = 0x40
    time_ms: int = wire(U32(unit="ms"), 0)
    state: BoardState = wire(Enum8(BoardState), BoardState.BOOT)
    mode: ControlMode = wire(Enum8(ControlMode), ControlMode.SETPOINT)
    watchdog: WatchdogState = wire(Enum8(WatchdogState), WatchdogState.OK)
    power: PowerState = wire(Enum8(PowerState), PowerState.NORMAL)
    faults: int = wire(U16(), 0)
    link_age_ms: int = wire(U16(unit="ms"), 0)
    battery_mv: int = wire(U16(unit="mV"), 0)
    battery_ma: int = wire(U16(unit="mA"), 0)
    battery_soc: int = wire(U8(0, 100, "%"), 0)
    ubec_mv: int = wire(U16(unit="mV"), 0)
    ubec_ma: int = wire(U16(unit="mA"), 0)
    rx_frames: int = wire(U32(), 0)
    rx_bad: int = wire(U32(), 0)
    seq_gaps: int = wire(U32(), 0)
    pulses_us: tuple[int, ...] = wire(Array(U16(0, PULSE_MAX_US, "us"), 0, MAX_CHANNELS), ())
    units: tuple[UnitState, ...] = wire(Array(UnitState, 0, MAX_UNITS), ())


@dataclass(frozen=True, slots=True)
class EscCalibrationStatus(Message):
    """B→H: the ESC endpoint procedure, on every phase change and at the telemetry rate while it runs."""

    MSG_ID: ClassVar[int] = 0x41
    unit: int = wire(U8(0, MAX_UNITS - 1), 0)
    phase: EscCalPhase = wire(Enum8(EscCalPhase), EscCalPhase.IDLE)
    abort: EscCalAbort = wire(Enum8(EscCalAbort), EscCalAbort.NONE)
    pulse_us: int = wire(U16(0, PULSE_MAX_US, "us"), 0)
    supply_on: int = wire(U8(0, 1), 1)
    phase_ms: int = wire(U32(unit="ms"), 0)


@dataclass(frozen=True, slots=True)
class Log(Message):
    """B→H: a state change or fault, as text."""

    MSG_ID: ClassVar[int] = 0x50
    severity: Severity = wire(Enum8(Severity), Severity.INFO)
    code: int = wire(U16(), 0)
    text: str = wire(Text(200), "")


CATALOGUE: tuple[type[Message], ...] = (
    Hello,
    HelloReply,
    Heartbeat,
    Arm,
    Disarm,
    SetMode,
    Ack,
    Nack,
    EscCalibrate,
    ActuatorSetpoint,
    RawPulses,
    CalibrationData,
    CalibrationRequest,
    Telemetry,
    EscCalibrationStatus,
    Log,
)
BY_ID: dict[int, type[Message]] = {cls.MSG_ID: cls for cls in CATALOGUE}
LAYOUTS: dict[int, Layout] = {cls.MSG_ID: layout_of(cls) for cls in CATALOGUE}
assert len(BY_ID) == len(CATALOGUE), "duplicate message id"
CODECS: CodecTable = CodecTable(BY_ID, PROTOCOL_VERSION)
"""The generated encoder and decoder of each message (:mod:`protocol.compiled`), each generated on first
use; ``LAYOUTS`` is their reference, and what words every error."""


def schema_text() -> str:
    """Canonical description of the catalogue; one line per message, id order."""
    return "\n".join(
        f"{cls.MSG_ID:#04x} {cls.__name__} reliable={int(cls.RELIABLE)} {LAYOUTS[cls.MSG_ID].signature()}"
        for cls in sorted(CATALOGUE, key=lambda c: c.MSG_ID)
    )


def _schema_hash() -> int:
    digest = hashlib.sha256(f"vscmg-hil protocol v{PROTOCOL_VERSION}\n{schema_text()}".encode()).digest()
    value: int = struct.unpack("<I", digest[:4])[0]
    return value


SCHEMA_HASH: int = _schema_hash()
"""First four bytes (little-endian u32) of SHA-256 over ``schema_text()``: both ends must agree."""


def encode_payload(msg: Any) -> bytes:
    """The payload bytes of ``msg``. Raises :class:`FieldRangeError` for an out-of-range field."""
    body = CODECS[msg.MSG_ID].encode(msg, 0, 0)
    if body is not None:
        return body[4:]  # after the header the generated encoder puts in front
    out = bytearray()
    LAYOUTS[msg.MSG_ID].encode_into(msg, out, type(msg).__name__)
    return bytes(out)
