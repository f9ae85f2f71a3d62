"""Canonical test vectors of the wire protocol, and the check of a codec against them.

``fixtures/protocol_vectors.json`` is generated from this module (``python -m protocol vectors --write``)
and read by every implementation of the protocol — this Python codec (``hil selftest``, the tests) and
the C firmware — to test itself in both directions:

* ``frames``: one or more canonical frames per message of the catalogue: the message's field values,
  its payload, the unencoded frame (header + payload + CRC) and the bytes on the wire (COBS + 0x00).
  *Encode* the fields with the given ``seq``/``flags`` and you must get ``wire_hex`` exactly; *decode*
  ``wire_hex`` and you must get the fields, ``seq`` and ``flags``.
* ``bad_frames``: deliberately broken wire bytes, each with the ``reason`` a receiver must report
  (one of :class:`protocol.frame.BadFrameReason`'s values) and a note saying what is wrong.
* ``streams``: byte streams (several frames, garbage, idle delimiters) with the exact sequence of events
  a deframer must produce.
* ``cobs`` and ``crc``: the two primitives on their own, including COBS's 254-byte block edge cases.

Field values are JSON-friendly and exact: integers as numbers, enums as ``{"name", "value"}``, text as
strings, blobs as lowercase hex, records as objects, arrays as lists; every float is a float32 value
written as the shortest decimal that round-trips the double holding it (parse it as a double, then
narrow to float32 without loss).

Everything here is pure (no file I/O) except :func:`check_vectors`, the thin entry point that reads the
file for ``hil selftest``; :func:`check_document` does the checking on an already-parsed document.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from . import cobs
from .crc import crc16_ccitt_false
from .errors import FrameError, ProtocolError
from .fields import Array, Blob, Enum8, Scalar, Text, layout_of
from .frame import (
    CRC,
    DELIMITER,
    HEADER,
    MAX_ENCODED,
    BadFrame,
    BadFrameReason,
    Deframer,
    Frame,
    encode_frame,
)
from .messages import (
    BY_ID,
    CATALOGUE,
    GIMBAL_ANGLE_LIMIT,
    GIMBAL_RATE_LIMIT,
    MAX_CALIBRATION_CHUNK,
    MAX_CHANNELS,
    MAX_UNITS,
    PROTOCOL_VERSION,
    PULSE_MAX_US,
    PULSE_MIN_US,
    ROTOR_SPEED_LIMIT,
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
    encode_payload,
    schema_text,
)

_F32 = struct.Struct("<f")
FORMAT = "vscmg-hil protocol test vectors"
FORMAT_VERSION = 1
"""Version of this file's layout (not of the protocol): bumped only if keys change meaning."""


# =========================================================================== field values <-> JSON
def to_json(obj: Any) -> dict[str, Any]:
    """The JSON-friendly field values of a message or record dataclass (wire order)."""
    return {name: _value_to_json(codec, getattr(obj, name)) for name, codec in layout_of(type(obj)).fields}


def _value_to_json(codec: Any, value: Any) -> Any:
    if isinstance(codec, Enum8):
        return {"name": codec.enum_cls(value).name, "value": int(value)}
    if isinstance(codec, Blob):
        return bytes(value).hex()
    if isinstance(codec, Array):
        if isinstance(codec.item, Scalar):
            return [_value_to_json(codec.item, v) for v in value]
        return [to_json(v) for v in value]
    if isinstance(codec, Scalar) and codec.fmt == "f":
        return float(value)
    return value  # int or str


def from_json(cls: type, values: Mapping[str, Any], where: str = "") -> Any:
    """Build ``cls`` (a message or record dataclass) from :func:`to_json`'s form.

    Strict: a missing or unknown key, a wrong JSON type or an enum whose name and value disagree raises
    :class:`ProtocolError` naming the path (``where``). Ranges are *not* checked here: encoding does that.
    """
    where = where or cls.__name__
    if not isinstance(values, Mapping):
        raise ProtocolError(f"{where}: expected an object, got {type(values).__name__}")
    layout = layout_of(cls)
    names = [name for name, _ in layout.fields]
    extra = sorted(set(values) - set(names))
    missing = [n for n in names if n not in values]
    if extra or missing:
        raise ProtocolError(f"{where}: unknown field(s) {extra}, missing field(s) {missing}")
    kwargs = {name: _value_from_json(codec, values[name], f"{where}.{name}") for name, codec in layout.fields}
    return cls(**kwargs)


def _value_from_json(codec: Any, value: Any, where: str) -> Any:
    if isinstance(codec, Enum8):
        if not isinstance(value, Mapping) or set(value) != {"name", "value"}:
            raise ProtocolError(f"{where}: expected {{'name', 'value'}}, got {value!r}")
        try:
            member = codec.enum_cls[value["name"]]
        except KeyError:
            raise ProtocolError(f"{where}: {value['name']!r} is not a {codec.enum_cls.__name__}") from None
        if int(member) != value["value"]:
            raise ProtocolError(f"{where}: {member.name} is {int(member)}, not {value['value']!r}")
        return member
    if isinstance(codec, Blob):
        if not isinstance(value, str):
            raise ProtocolError(f"{where}: expected a hex string, got {value!r}")
        try:
            return bytes.fromhex(value)
        except ValueError:
            raise ProtocolError(f"{where}: {value!r} is not hex") from None
    if isinstance(codec, Text):
        if not isinstance(value, str):
            raise ProtocolError(f"{where}: expected a string, got {value!r}")
        return value
    if isinstance(codec, Array):
        if not isinstance(value, list):
            raise ProtocolError(f"{where}: expected a list, got {value!r}")
        if isinstance(codec.item, Scalar):
            return tuple(_value_from_json(codec.item, v, f"{where}[{i}]") for i, v in enumerate(value))
        return tuple(from_json(codec.item, v, f"{where}[{i}]") for i, v in enumerate(value))
    if codec.fmt == "f":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ProtocolError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ProtocolError(f"{where}: expected an integer, got {value!r}")
    return value


# =========================================================================== catalogue facts
def payload_size_range(cls: type) -> tuple[int, int]:
    """Smallest and largest payload (bytes) a message class can have on the wire."""
    lo = hi = 0
    for _, codec in layout_of(cls).fields:
        if isinstance(codec, Scalar):
            lo += codec.size
            hi += codec.size
        elif isinstance(codec, (Text, Blob)):
            lo += 1
            hi += 1 + codec.max_len
        else:
            item = codec.item
            size = item.size if isinstance(item, Scalar) else payload_size_range(item)[1]
            lo += 1 + codec.min_count * size
            hi += 1 + codec.max_count * size
    return lo, hi


def _describe_catalogue() -> list[dict[str, Any]]:
    rows = []
    for cls in sorted(CATALOGUE, key=lambda c: c.MSG_ID):
        lo, hi = payload_size_range(cls)
        rows.append(
            {
                "name": cls.__name__,
                "msg_id": cls.MSG_ID,
                "reliable": cls.RELIABLE,
                "payload_min": lo,
                "payload_max": hi,
            }
        )
    return rows


# =========================================================================== building frames by hand
def build_wire(
    msg_id: int, payload: bytes, seq: int = 0, flags: int = 0, version: int = PROTOCOL_VERSION
) -> bytes:
    """Wire bytes of a frame from raw parts, with a *correct* CRC: how the bad-frame vectors smuggle
    values that :func:`protocol.frame.encode_frame` refuses (wrong version, unknown id, bad payload)."""
    body = HEADER.pack(version, msg_id, seq, flags) + payload
    return cobs.encode(body + CRC.pack(crc16_ccitt_false(body))) + DELIMITER


def _f32(x: float) -> float:
    """``x`` rounded to float32 (what the wire carries)."""
    return float(_F32.unpack(_F32.pack(x))[0])


# =========================================================================== the canonical frames
@dataclass(frozen=True)
class _Good:
    name: str
    message: Any
    seq: int = 0
    flags: int = 0
    note: str = ""


def _good_vectors() -> list[_Good]:
    units4 = tuple(
        UnitSetpoint(gimbal=_f32(g), rotor_speed=_f32(w))
        for g, w in ((0.5, 450.0), (-0.25, 450.0), (0.125, -300.5), (-1.0, 0.0))
    )
    states4 = tuple(
        UnitState(gimbal_angle=_f32(a), gimbal_rate=_f32(r), rotor_speed=_f32(w))
        for a, r, w in ((0.1, 0.5, 420.0), (-0.2, -0.25, 430.5), (3.0, 0.0, 0.0), (-6.283185, 1.5, -12.75))
    )
    long_text = "Δ" * 100  # 200 bytes of two-byte UTF-8
    return [
        _Good(
            "Hello/typical",
            Hello(
                protocol_version=PROTOCOL_VERSION,
                schema_hash=SCHEMA_HASH,
                manufacturer="vscmg-hil",
                model="hil-host",
                description="VSCMG HIL host",
                version="1.0",
                uri="https://example.invalid/vscmg",
                serial="HOST0001",
            ),
            seq=0,
            note="the host's first frame: version and schema hash of this catalogue",
        ),
        _Good(
            "Hello/empty_strings",
            Hello(protocol_version=255, schema_hash=0xFFFFFFFF),
            seq=255,
            flags=int(Flags.RETRANSMIT),
            note="every string empty (length byte 0); a retransmission",
        ),
        _Good(
            "Hello/max_lengths",
            Hello(
                protocol_version=1,
                schema_hash=0x00010000,
                manufacturer="M" * 24,
                model="m" * 24,
                description="d" * 48,
                version="v" * 16,
                uri="u" * 64,
                serial="s" * 24,
            ),
            seq=7,
            note="every identity string at its maximum length",
        ),
        _Good(
            "HelloReply/typical",
            HelloReply(
                protocol_version=PROTOCOL_VERSION,
                schema_hash=SCHEMA_HASH,
                reset_cause=ResetCause.WATCHDOG,
                state=BoardState.DISARMED,
                n_units=4,
                frame_rate_hz=50,
                manufacturer="vscmg-hil",
                model="ADK-VSCMG",
                description="ADK board, 4 VSCMG units",
                version="1.0",
                uri="https://example.invalid/vscmg-hil",
                serial="SIM0001",
                firmware_build="fw 2024-01-01 µC",
            ),
            seq=0,
            note="after an MCU watchdog reset; firmware_build holds non-ASCII UTF-8",
        ),
        _Good(
            "HelloReply/max",
            HelloReply(
                protocol_version=255,
                schema_hash=0x80000000,
                reset_cause=ResetCause.SOFTWARE,
                state=BoardState.FAILSAFE,
                n_units=MAX_UNITS,
                frame_rate_hz=500,
                manufacturer="M" * 24,
                model="m" * 24,
                description="d" * 48,
                version="v" * 16,
                uri="u" * 64,
                serial="s" * 24,
                firmware_build="b" * 24,
            ),
            seq=200,
            note="the longest frame of the catalogue",
        ),
        _Good("Heartbeat/host", Heartbeat(time_ms=0, state=0), seq=1, note="host heartbeat: state 0"),
        _Good(
            "Heartbeat/board",
            Heartbeat(time_ms=0xDEADBEEF, state=int(BoardState.ARMED)),
            seq=128,
            note="board heartbeat: uptime in ms, state ARMED",
        ),
        _Good("Arm/typical", Arm(), seq=3, flags=int(Flags.ACK_REQUESTED), note="reliable, empty payload"),
        _Good(
            "Arm/retransmit",
            Arm(),
            seq=3,
            flags=int(Flags.ACK_REQUESTED | Flags.RETRANSMIT),
            note="the retry of Arm/typical: same seq, RETRANSMIT added",
        ),
        _Good("Disarm/typical", Disarm(), seq=4, flags=int(Flags.ACK_REQUESTED)),
        _Good(
            "SetMode/raw_pulses", SetMode(mode=ControlMode.RAW_PULSES), seq=5, flags=int(Flags.ACK_REQUESTED)
        ),
        _Good(
            "SetMode/esc_calibration",
            SetMode(mode=ControlMode.ESC_CALIBRATION),
            seq=6,
            flags=int(Flags.ACK_REQUESTED),
        ),
        _Good("Ack/typical", Ack(msg_id=Arm.MSG_ID, seq=3), seq=9, note="answers Arm/typical"),
        _Good("Ack/zero_fields", Ack(msg_id=0, seq=0), seq=0, note="payload of zeros: COBS at work"),
        _Good("Nack/power", Nack(msg_id=Arm.MSG_ID, seq=3, reason=NackReason.POWER), seq=10),
        _Good(
            "Nack/bad_calibration",
            Nack(msg_id=CalibrationData.MSG_ID, seq=255, reason=NackReason.BAD_CALIBRATION),
            seq=11,
        ),
        _Good(
            "ActuatorSetpoint/4_units_rate",
            ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=units4),
            seq=42,
            note="the paper's 4-unit pyramid: gimbal rates (rad/s) and rotor speeds (rad/s)",
        ),
        _Good(
            "ActuatorSetpoint/1_unit_angle_limits",
            ActuatorSetpoint(
                gimbal_mode=GimbalMode.ANGLE,
                units=(UnitSetpoint(gimbal=-GIMBAL_ANGLE_LIMIT, rotor_speed=ROTOR_SPEED_LIMIT),),
            ),
            seq=43,
            note="one unit, both fields at their range limits",
        ),
        _Good(
            "ActuatorSetpoint/8_units_zero",
            ActuatorSetpoint(units=(UnitSetpoint(),) * MAX_UNITS),
            seq=44,
            note="the most units; all-zero floats",
        ),
        _Good(
            "RawPulses/8_channels",
            RawPulses(pulses_us=(1500, 1000, 1500, 1250, 1500, 1750, 1480, 2000)),
            seq=12,
            note="gimbal 0, rotor 0, gimbal 1, rotor 1, ...",
        ),
        _Good(
            "RawPulses/limits",
            RawPulses(pulses_us=(PULSE_MIN_US,) + (PULSE_MAX_US,) * (MAX_CHANNELS - 1)),
            seq=13,
            note="16 channels at the pulse-width limits",
        ),
        _Good(
            "CalibrationData/first_fragment",
            CalibrationData(
                unit=2,
                transfer_id=9,
                index=0,
                count=3,
                total_len=450,
                set_crc=0x1D0F,
                chunk=bytes(range(MAX_CALIBRATION_CHUNK)),
            ),
            seq=20,
            flags=int(Flags.ACK_REQUESTED),
            note="a full 200-byte chunk, including zero bytes",
        ),
        _Good(
            "CalibrationData/last_fragment",
            CalibrationData(
                unit=2,
                transfer_id=9,
                index=2,
                count=3,
                total_len=450,
                set_crc=0x1D0F,
                chunk=bytes([0xFF] * 50),
            ),
            seq=22,
            flags=int(Flags.ACK_REQUESTED),
        ),
        _Good(
            "CalibrationData/empty_set",
            CalibrationData(
                unit=MAX_UNITS - 1, transfer_id=0, index=0, count=1, total_len=0, set_crc=0xFFFF, chunk=b""
            ),
            seq=23,
            flags=int(Flags.ACK_REQUESTED),
            note="a zero-length set: one empty fragment",
        ),
        _Good(
            "CalibrationRequest/typical",
            CalibrationRequest(unit=1, transfer_id=200),
            seq=30,
            flags=int(Flags.ACK_REQUESTED),
        ),
        _Good(
            "Telemetry/4_units",
            Telemetry(
                time_ms=123456,
                state=BoardState.ARMED,
                mode=ControlMode.SETPOINT,
                watchdog=WatchdogState.OK,
                power=PowerState.WARN,
                faults=int(FaultFlag.BATTERY_LOW | FaultFlag.SETPOINT_CLAMPED),
                link_age_ms=20,
                battery_mv=11480,
                battery_ma=2350,
                battery_soc=63,
                ubec_mv=5010,
                ubec_ma=870,
                rx_frames=100000,
                rx_bad=3,
                seq_gaps=1,
                pulses_us=(1500, 1400, 1510, 1400, 1490, 1420, 1500, 1380),
                units=states4,
            ),
            seq=77,
            note="4 units, 8 channels",
        ),
        _Good("Telemetry/boot_empty", Telemetry(), seq=0, note="no channels, no units, everything zero"),
        _Good(
            "Telemetry/failsafe_max",
            Telemetry(
                time_ms=0xFFFFFFFF,
                state=BoardState.FAILSAFE,
                mode=ControlMode.RAW_PULSES,
                watchdog=WatchdogState.LINK_LOST,
                power=PowerState.BROWN_OUT,
                faults=0xFFFF,
                link_age_ms=0xFFFF,
                battery_mv=0xFFFF,
                battery_ma=0xFFFF,
                battery_soc=100,
                ubec_mv=0xFFFF,
                ubec_ma=0xFFFF,
                rx_frames=0xFFFFFFFF,
                rx_bad=0xFFFFFFFF,
                seq_gaps=0xFFFFFFFF,
                pulses_us=(PULSE_MAX_US,) * MAX_CHANNELS,
                units=(
                    UnitState(
                        gimbal_angle=GIMBAL_ANGLE_LIMIT,
                        gimbal_rate=-GIMBAL_RATE_LIMIT,
                        rotor_speed=-ROTOR_SPEED_LIMIT,
                    ),
                )
                * MAX_UNITS,
            ),
            seq=255,
            note="every field at its maximum (negative limits for the floats)",
        ),
        _Good("Log/info", Log(severity=Severity.INFO, code=2, text="state DISARMED -> ARMED"), seq=50),
        _Good(
            "Log/max_text",
            Log(severity=Severity.CRITICAL, code=0xFFFF, text=long_text),
            seq=51,
            note="200 bytes of UTF-8 (100 × 'Δ')",
        ),
        _Good("Log/empty", Log(severity=Severity.DEBUG, code=0, text=""), seq=52),
    ]


# =========================================================================== the broken frames
@dataclass(frozen=True)
class _Bad:
    name: str
    wire: bytes
    reason: BadFrameReason
    note: str


def _payload(msg: Any) -> bytes:
    return encode_payload(msg)


def _bad_vectors() -> list[_Bad]:
    ack = encode_frame(Ack(msg_id=Arm.MSG_ID, seq=3), 9)
    body = cobs.decode(ack[:-1])
    flipped = bytearray(body)
    flipped[4] ^= 0x01  # payload bit, CRC left as it was
    swapped_crc = body[:-2] + body[-1:] + body[-2:-1]
    setpoint = _payload(ActuatorSetpoint(units=(UnitSetpoint(gimbal=0.5, rotor_speed=100.0),)))
    nan_setpoint = bytearray(setpoint)
    nan_setpoint[2:6] = b"\x00\x00\xc0\x7f"  # quiet NaN as gimbal of unit 0
    big_rotor = bytearray(setpoint)
    big_rotor[6:10] = bytes.fromhex("00803b45")  # 3000.0 rad/s > ROTOR_SPEED_LIMIT
    pulses = bytearray(_payload(RawPulses(pulses_us=(1500, 1500))))
    pulses[3:5] = (3000).to_bytes(2, "little")
    log = _payload(Log(text="ok"))
    return [
        _Bad(
            "crc/payload_bit_flipped",
            cobs.encode(bytes(flipped)) + DELIMITER,
            BadFrameReason.CRC,
            "Ack/typical with one payload bit flipped and the CRC left unchanged",
        ),
        _Bad(
            "crc/bytes_swapped",
            cobs.encode(swapped_crc) + DELIMITER,
            BadFrameReason.CRC,
            "Ack/typical with the CRC's two bytes swapped (CRC is little-endian on the wire)",
        ),
        _Bad(
            "cobs/group_overruns",
            bytes.fromhex("0a01020300"),
            BadFrameReason.COBS,
            "the first code byte (0x0a) announces 9 data bytes but only 3 follow",
        ),
        _Bad(
            "too_short/five_bytes",
            cobs.encode(bytes.fromhex("0113090300")) + DELIMITER,
            BadFrameReason.TOO_SHORT,
            "5 bytes after COBS decoding: less than header (4) + CRC (2)",
        ),
        _Bad(
            "too_short/one_byte",
            bytes.fromhex("0100"),
            BadFrameReason.TOO_SHORT,
            "the COBS group 0x01 alone decodes to zero bytes",
        ),
        _Bad(
            "too_long/259_bytes_no_delimiter",
            b"\x01" * (MAX_ENCODED + 1) + DELIMITER,
            BadFrameReason.TOO_LONG,
            f"{MAX_ENCODED + 1} bytes before a delimiter: longer than any encoded frame ({MAX_ENCODED})",
        ),
        _Bad(
            "too_long/257_byte_body",
            cobs.encode(bytes(257)) + DELIMITER,
            BadFrameReason.TOO_LONG,
            "valid COBS of 257 zero bytes: longer than header + 250-byte payload + CRC (256)",
        ),
        _Bad(
            "version/2",
            build_wire(Ack.MSG_ID, bytes([Arm.MSG_ID, 3]), seq=9, version=2),
            BadFrameReason.VERSION,
            "an Ack with protocol version 2 in the header (CRC correct)",
        ),
        _Bad(
            "version/0",
            build_wire(Heartbeat.MSG_ID, _payload(Heartbeat()), version=0),
            BadFrameReason.VERSION,
            "a Heartbeat with protocol version 0",
        ),
        _Bad(
            "unknown_id/0x7f",
            build_wire(0x7F, b""),
            BadFrameReason.UNKNOWN_ID,
            "message id 0x7f is not in the catalogue",
        ),
        _Bad(
            "length/ack_short",
            build_wire(Ack.MSG_ID, bytes([Arm.MSG_ID])),
            BadFrameReason.LENGTH,
            "an Ack payload of 1 byte (needs 2)",
        ),
        _Bad(
            "length/heartbeat_trailing",
            build_wire(Heartbeat.MSG_ID, _payload(Heartbeat()) + b"\x00"),
            BadFrameReason.LENGTH,
            "a Heartbeat with one trailing byte after its fields",
        ),
        _Bad(
            "length/arm_with_payload",
            build_wire(Arm.MSG_ID, b"\x01", flags=int(Flags.ACK_REQUESTED)),
            BadFrameReason.LENGTH,
            "Arm has no fields, this one carries a byte",
        ),
        _Bad(
            "length/text_past_end",
            build_wire(Log.MSG_ID, log[:-1]),
            BadFrameReason.LENGTH,
            "a Log whose text length byte (2) runs one byte past the payload's end",
        ),
        _Bad(
            "length/units_past_end",
            build_wire(ActuatorSetpoint.MSG_ID, setpoint[:-4]),
            BadFrameReason.LENGTH,
            "an ActuatorSetpoint announcing 1 unit with only 4 of its 8 bytes",
        ),
        _Bad(
            "field_range/enum",
            build_wire(SetMode.MSG_ID, b"\x07", flags=int(Flags.ACK_REQUESTED)),
            BadFrameReason.FIELD_RANGE,
            "SetMode.mode = 7 is not a ControlMode",
        ),
        _Bad(
            "field_range/nan",
            build_wire(ActuatorSetpoint.MSG_ID, bytes(nan_setpoint)),
            BadFrameReason.FIELD_RANGE,
            "ActuatorSetpoint.units[0].gimbal is NaN (0x7fc00000): no float field accepts NaN or infinity",
        ),
        _Bad(
            "field_range/rotor_speed",
            build_wire(ActuatorSetpoint.MSG_ID, bytes(big_rotor)),
            BadFrameReason.FIELD_RANGE,
            f"ActuatorSetpoint.units[0].rotor_speed = 3000.0 rad/s > {ROTOR_SPEED_LIMIT:g}",
        ),
        _Bad(
            "field_range/unit_count",
            build_wire(
                ActuatorSetpoint.MSG_ID, b"\x00" + bytes([MAX_UNITS + 1]) + bytes(8 * (MAX_UNITS + 1))
            ),
            BadFrameReason.FIELD_RANGE,
            f"ActuatorSetpoint with {MAX_UNITS + 1} units (at most {MAX_UNITS})",
        ),
        _Bad(
            "field_range/zero_units",
            build_wire(ActuatorSetpoint.MSG_ID, b"\x00\x00"),
            BadFrameReason.FIELD_RANGE,
            "ActuatorSetpoint with 0 units (at least 1)",
        ),
        _Bad(
            "field_range/pulse_width",
            build_wire(RawPulses.MSG_ID, bytes(pulses)),
            BadFrameReason.FIELD_RANGE,
            f"RawPulses.pulses_us[1] = 3000 us > {PULSE_MAX_US}",
        ),
        _Bad(
            "field_range/utf8",
            build_wire(Log.MSG_ID, log[:3] + b"\x02\xc3\x28"),
            BadFrameReason.FIELD_RANGE,
            "Log.text is not valid UTF-8 (0xc3 0x28)",
        ),
        _Bad(
            "field_range/text_too_long",
            build_wire(Hello.MSG_ID, b"\x01" + bytes(4) + b"\x19" + b"M" * 25 + b"\x00" * 5),
            BadFrameReason.FIELD_RANGE,
            "Hello.manufacturer of 25 bytes (at most 24)",
        ),
        _Bad(
            "field_range/protocol_version_0",
            build_wire(Hello.MSG_ID, b"\x00" + bytes(4) + bytes(6)),
            BadFrameReason.FIELD_RANGE,
            "Hello.protocol_version = 0 (1..255)",
        ),
        _Bad(
            "field_range/soc",
            build_wire(Telemetry.MSG_ID, _telemetry_with_soc(101)),
            BadFrameReason.FIELD_RANGE,
            "Telemetry.battery_soc = 101 % (0..100)",
        ),
    ]


def _telemetry_with_soc(soc: int) -> bytes:
    payload = bytearray(_payload(Telemetry()))
    payload[16] = soc  # time 4, state/mode/watchdog/power 4, faults/link_age/battery_mv/battery_ma 8
    return bytes(payload)


# =========================================================================== streams
@dataclass(frozen=True)
class _Stream:
    """``parts`` are ("good", frame vector name) | ("bad", bad vector name) | ("raw", bytes);
    ``events`` the expected events: ("frame", name) | ("bad", reason)."""

    name: str
    parts: tuple[tuple[str, Any], ...]
    events: tuple[tuple[str, str], ...]
    note: str


def _stream_vectors() -> list[_Stream]:
    crc = BadFrameReason.CRC.value
    return [
        _Stream(
            "idle_and_garbage",
            (
                ("raw", b"\x00\x00"),
                ("good", "Heartbeat/host"),
                ("raw", b"\x00\x00\x00"),
                ("good", "Ack/typical"),
            ),
            (("frame", "Heartbeat/host"), ("frame", "Ack/typical")),
            "delimiters on their own are idle fill: no event",
        ),
        _Stream(
            "resync_after_corruption",
            (
                ("good", "Arm/typical"),
                ("bad", "crc/payload_bit_flipped"),
                ("good", "Telemetry/4_units"),
                ("bad", "cobs/group_overruns"),
                ("good", "Log/info"),
            ),
            (
                ("frame", "Arm/typical"),
                ("bad", crc),
                ("frame", "Telemetry/4_units"),
                ("bad", BadFrameReason.COBS.value),
                ("frame", "Log/info"),
            ),
            "a corrupt frame costs that frame only",
        ),
        _Stream(
            "lost_delimiter_merges_two",
            (("raw", encode_frame(Heartbeat(time_ms=1), 1)[:-1]), ("good", "Ack/typical")),
            (("bad", crc),),
            "a frame whose delimiter was lost runs into the next one: one bad frame (the two bodies joined "
            "by a decoded 0x00 fail the CRC), then the stream is in sync again",
        ),
    ]


# =========================================================================== the document
def build_document() -> dict[str, Any]:
    """The whole vectors document (pure: what ``--write`` serialises)."""
    goods = _good_vectors()
    bads = _bad_vectors()
    frames = []
    for g in goods:
        wire = encode_frame(g.message, g.seq, g.flags)
        body = cobs.decode(wire[:-1])
        frames.append(
            {
                "name": g.name,
                "message": type(g.message).__name__,
                "msg_id": g.message.MSG_ID,
                "seq": g.seq,
                "flags": g.flags,
                "flag_names": _flag_names(g.flags),
                "fields": to_json(g.message),
                "payload_len": len(body) - 6,
                "payload_hex": body[4:-2].hex(),
                "crc": f"0x{int.from_bytes(body[-2:], 'little'):04x}",
                "frame_hex": body.hex(),
                "wire_hex": wire.hex(),
                "note": g.note,
            }
        )
    bad_frames = []
    for b in bads:
        try:
            decoded: str | None = cobs.decode(b.wire[:-1]).hex()
        except FrameError:
            decoded = None
        bad_frames.append(
            {
                "name": b.name,
                "reason": b.reason.value,
                "wire_hex": b.wire.hex(),
                "frame_hex": decoded,
                "note": b.note,
            }
        )
    wires = {f["name"]: bytes.fromhex(f["wire_hex"]) for f in frames}
    wires.update((b.name, b.wire) for b in bads)
    streams = [
        {
            "name": st.name,
            "wire_hex": b"".join(ref if kind == "raw" else wires[ref] for kind, ref in st.parts).hex(),
            "events": [{kind: ref} for kind, ref in st.events],
            "note": st.note,
        }
        for st in _stream_vectors()
    ]
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "protocol_version": PROTOCOL_VERSION,
        "schema_hash": f"0x{SCHEMA_HASH:08x}",
        "about": _ABOUT,
        "messages": _describe_catalogue(),
        "frames": frames,
        "bad_frames": bad_frames,
        "streams": streams,
        "cobs": [{"decoded_hex": d.hex(), "encoded_hex": cobs.encode(d).hex()} for d in _cobs_cases()],
        "crc": [{"data_hex": d.hex(), "crc": f"0x{crc16_ccitt_false(d):04x}"} for d in _crc_cases()],
        "schema_text": schema_text().splitlines(),
    }


_ABOUT = [
    "Test vectors of the vscmg-hil wire protocol (docs/protocol.md). Generated by "
    "`python -m protocol vectors --write fixtures/protocol_vectors.json`; do not edit by hand.",
    "frames: encode `fields` with `seq` and `flags` -> `wire_hex` exactly; decode `wire_hex` -> the same.",
    "wire_hex = COBS(frame_hex) + 00; frame_hex = version, msg_id, seq, flags, payload, CRC-16 (LE).",
    "crc = CRC-16/CCITT-FALSE (poly 0x1021, init 0xffff, no reflection, xorout 0) over header + payload.",
    "Enums are {name, value}; blobs are hex; floats are float32 values printed as exact doubles.",
    "bad_frames: feed `wire_hex` to a deframer: exactly one bad-frame event with `reason`.",
    "streams: feed `wire_hex` to a new deframer: exactly `events` in order ({frame: name} | {bad: reason}).",
    "cobs, crc: the primitives alone (COBS canonical form: a 254-byte block is 0xff + 254 bytes).",
    "schema_text: the catalogue text whose SHA-256 (first 4 bytes, little-endian u32) is schema_hash.",
]


def _flag_names(flags: int) -> list[str]:
    return [f.name for f in Flags if f.value and flags & f.value and f.name]


def _cobs_cases() -> list[bytes]:
    return [
        b"",
        b"\x00",
        b"\x00\x00",
        b"\x11\x22\x00\x33",
        b"\x11\x22\x33\x44",
        b"\x11\x00\x00\x00",
        bytes(range(1, 254)),
        bytes(range(1, 255)),
        bytes(range(1, 256)),
        bytes(range(0, 256)),
        bytes(range(2, 256)) + b"\x00",
        bytes(range(3, 256)) + b"\x00\x01",
    ]


def _crc_cases() -> list[bytes]:
    return [b"123456789", b"", b"\x00", b"\xff\xff", bytes(range(256))]


def render_json(document: Mapping[str, Any]) -> str:
    """Stable text of the document (what the committed file must equal)."""
    return json.dumps(document, indent=1, ensure_ascii=False) + "\n"


# =========================================================================== checking
@dataclass(frozen=True, slots=True)
class VectorResult:
    """One check: ``name`` names the vector (or section), ``detail`` says what differed."""

    name: str
    ok: bool
    detail: str = ""


def check_vectors(path: str | Path) -> list[VectorResult]:
    """Check this codec against the vectors file at ``path`` (the one file read in ``protocol``).

    An unreadable or malformed file is one failed result, not an exception, so ``hil selftest`` can
    report it."""
    try:
        document = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        return [VectorResult(str(path), False, f"cannot read vectors: {exc}")]
    return check_document(document)


def check_document(document: Any) -> list[VectorResult]:
    """Every check of :func:`check_vectors` on an already-parsed document (pure)."""
    if not isinstance(document, Mapping) or document.get("format") != FORMAT:
        return [VectorResult("format", False, f"not a {FORMAT!r} document")]
    results = [_check_header(document)]
    frames = document.get("frames", [])
    for i, vector in enumerate(frames):
        results.append(_guarded(f"frames[{i}]", vector, _check_frame))
    for i, vector in enumerate(document.get("bad_frames", [])):
        results.append(_guarded(f"bad_frames[{i}]", vector, _check_bad))
    named = {v.get("name"): v for v in frames if isinstance(v, Mapping)}
    for i, vector in enumerate(document.get("streams", [])):
        results.append(_guarded(f"streams[{i}]", vector, lambda v: _check_stream(v, named)))
    for i, vector in enumerate(document.get("cobs", [])):
        results.append(_guarded(f"cobs[{i}]", vector, _check_cobs))
    for i, vector in enumerate(document.get("crc", [])):
        results.append(_guarded(f"crc[{i}]", vector, _check_crc))
    results.append(_check_messages(document.get("messages", [])))
    results.extend(_check_coverage(document))
    return results


def _guarded(where: str, vector: Any, check: Callable[[Mapping[str, Any]], list[str]]) -> VectorResult:
    name = vector.get("name", where) if isinstance(vector, Mapping) else where
    try:
        if not isinstance(vector, Mapping):
            raise ProtocolError("expected an object")
        problems = check(vector)
    except (ProtocolError, KeyError, TypeError, ValueError) as exc:
        problems = [f"malformed vector: {type(exc).__name__}: {exc}"]
    return VectorResult(str(name), not problems, "; ".join(problems))


def _check_header(document: Mapping[str, Any]) -> VectorResult:
    problems = []
    if document.get("format_version") != FORMAT_VERSION:
        problems.append(
            f"format_version {document.get('format_version')!r}, this checker reads {FORMAT_VERSION}"
        )
    if document.get("protocol_version") != PROTOCOL_VERSION:
        problems.append(
            f"protocol_version {document.get('protocol_version')!r}, codec speaks {PROTOCOL_VERSION}"
        )
    if document.get("schema_hash") != f"0x{SCHEMA_HASH:08x}":
        problems.append(f"schema_hash {document.get('schema_hash')!r}, codec's is 0x{SCHEMA_HASH:08x}")
    return VectorResult("header", not problems, "; ".join(problems))


def _check_frame(v: Mapping[str, Any]) -> list[str]:
    problems: list[str] = []
    cls = BY_ID.get(v["msg_id"])
    if cls is None or cls.__name__ != v["message"]:
        return [f"message {v['message']!r} with id {v['msg_id']!r} is not in the catalogue"]
    wire = bytes.fromhex(v["wire_hex"])
    message = from_json(cls, v["fields"], f"{v['name']}.fields")
    # encode direction
    try:
        encoded = encode_frame(message, v["seq"], v["flags"])
    except ProtocolError as exc:
        problems.append(f"encode raised {exc}")
    else:
        if encoded != wire:
            problems.append(f"encode gave {encoded.hex()}, vector has {wire.hex()}")
    if _flag_names(v["flags"]) != v["flag_names"]:
        problems.append(f"flag_names {v['flag_names']} do not match flags {v['flags']}")
    # decode direction, through the same path a receiver uses
    events = Deframer().feed(wire)
    if len(events) != 1 or not isinstance(events[0], Frame):
        problems.append(f"deframer gave {_describe_events(events)}, expected one frame")
        return problems
    frame = events[0]
    if frame.message != message:
        problems.append(f"decoded {to_json(frame.message)}, vector has {v['fields']}")
    if to_json(frame.message) != v["fields"]:
        problems.append("decoded fields do not serialise back to the vector's JSON")
    if (frame.seq, int(frame.flags)) != (v["seq"], v["flags"]):
        problems.append(
            f"decoded seq/flags {frame.seq}/{int(frame.flags)}, vector has {v['seq']}/{v['flags']}"
        )
    body = cobs.decode(wire[:-1])
    if body.hex() != v["frame_hex"] or body[4:-2].hex() != v["payload_hex"]:
        problems.append("frame_hex/payload_hex disagree with wire_hex")
    if len(body) - 6 != v["payload_len"] or f"0x{int.from_bytes(body[-2:], 'little'):04x}" != v["crc"]:
        problems.append("payload_len/crc disagree with wire_hex")
    return problems


def _check_bad(v: Mapping[str, Any]) -> list[str]:
    expected = BadFrameReason(v["reason"])
    events = Deframer().feed(bytes.fromhex(v["wire_hex"]))
    if len(events) == 1 and isinstance(events[0], BadFrame) and events[0].reason is expected:
        return []
    return [f"deframer gave {_describe_events(events)}, expected one bad frame ({expected.value})"]


def _check_stream(v: Mapping[str, Any], frames: Mapping[Any, Any]) -> list[str]:
    events = Deframer().feed(bytes.fromhex(v["wire_hex"]))
    got: list[dict[str, str]] = []
    for e in events:
        if isinstance(e, BadFrame):
            got.append({"bad": e.reason.value})
            continue
        match = next((n for n, f in frames.items() if _frame_matches(e, f)), None)
        got.append({"frame": match or f"<unlisted {type(e.message).__name__}>"})
    if got != list(v["events"]):
        return [f"events {got}, expected {v['events']}"]
    return []


def _frame_matches(frame: Frame, vector: Mapping[str, Any]) -> bool:
    return (
        type(frame.message).__name__ == vector.get("message")
        and frame.seq == vector.get("seq")
        and int(frame.flags) == vector.get("flags")
        and to_json(frame.message) == vector.get("fields")
    )


def _check_cobs(v: Mapping[str, Any]) -> list[str]:
    decoded, encoded = bytes.fromhex(v["decoded_hex"]), bytes.fromhex(v["encoded_hex"])
    problems = []
    if cobs.encode(decoded) != encoded:
        problems.append(f"encode gave {cobs.encode(decoded).hex()}")
    if cobs.decode(encoded) != decoded:
        problems.append(f"decode gave {cobs.decode(encoded).hex()}")
    return problems


def _check_crc(v: Mapping[str, Any]) -> list[str]:
    got = crc16_ccitt_false(bytes.fromhex(v["data_hex"]))
    return [] if f"0x{got:04x}" == v["crc"] else [f"crc 0x{got:04x}, vector has {v['crc']}"]


def _check_messages(rows: Any) -> VectorResult:
    if rows != _describe_catalogue():
        return VectorResult("messages", False, "the file's catalogue summary differs from this codec's")
    return VectorResult("messages", True)


def _check_coverage(document: Mapping[str, Any]) -> list[VectorResult]:
    """Every message has a canonical frame and every bad-frame reason a broken one."""
    covered = {v.get("message") for v in document.get("frames", []) if isinstance(v, Mapping)}
    missing = sorted(cls.__name__ for cls in CATALOGUE if cls.__name__ not in covered)
    reasons = {v.get("reason") for v in document.get("bad_frames", []) if isinstance(v, Mapping)}
    unseen = sorted(r.value for r in BadFrameReason if r.value not in reasons)
    return [
        VectorResult("coverage/messages", not missing, f"no vector for {missing}" if missing else ""),
        VectorResult("coverage/bad_reasons", not unseen, f"no bad frame for {unseen}" if unseen else ""),
    ]


def _describe_events(events: Sequence[Any]) -> str:
    parts = []
    for e in events:
        if isinstance(e, BadFrame):
            parts.append(f"bad({e.reason.value}: {e.detail})")
        else:
            parts.append(f"frame({type(e.message).__name__})")
    return "[" + ", ".join(parts) + "]"


__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "VectorResult",
    "build_document",
    "build_wire",
    "check_document",
    "check_vectors",
    "from_json",
    "payload_size_range",
    "render_json",
    "to_json",
]
