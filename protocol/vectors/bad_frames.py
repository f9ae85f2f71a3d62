"""Data: the broken frames of the vectors, each with the reason a receiver must report.

Most are built by hand with :func:`build_wire` (correct CRC, values :func:`protocol.frame.encode_frame`
refuses); the rest corrupt a good frame's bytes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .. import cobs
from ..crc import crc16_ccitt_false
from ..frame import CRC, DELIMITER, HEADER, MAX_ENCODED, BadFrameReason, encode_frame
from ..messages import (
    MAX_UNITS,
    PROTOCOL_VERSION,
    PULSE_MAX_US,
    ROTOR_SPEED_LIMIT,
    Ack,
    ActuatorSetpoint,
    Arm,
    Flags,
    Heartbeat,
    Hello,
    Log,
    RawPulses,
    SetMode,
    Telemetry,
    UnitSetpoint,
    encode_payload,
)


def build_wire(
    msg_id: int, payload: bytes, seq: int = 0, flags: int = 0, version: int = PROTOCOL_VERSION
) -> bytes:
    """Wire bytes of a frame from raw parts, with a *correct* CRC: how the bad-frame vectors smuggle
    values that :func:`protocol.frame.encode_frame` refuses (wrong version, unknown id, bad payload)."""
    body = HEADER.pack(version, msg_id, seq, flags) + payload
    return cobs.encode(body + CRC.pack(crc16_ccitt_false(body))) + DELIMITER


@dataclass(frozen=True)
class BadCase:
    """One broken frame: its ``wire`` bytes (with the delimiter) and the ``reason`` a receiver reports."""

    name: str
    wire: bytes
    reason: BadFrameReason
    note: str


def _payload(msg: Any) -> bytes:
    return encode_payload(msg)


def bad_cases() -> list[BadCase]:
    """Every broken frame, in file order (at least one per :class:`BadFrameReason`)."""
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
        BadCase(
            "crc/payload_bit_flipped",
            cobs.encode(bytes(flipped)) + DELIMITER,
            BadFrameReason.CRC,
            "Ack/typical with one payload bit flipped and the CRC left unchanged",
        ),
        BadCase(
            "crc/bytes_swapped",
            cobs.encode(swapped_crc) + DELIMITER,
            BadFrameReason.CRC,
            "Ack/typical with the CRC's two bytes swapped (CRC is little-endian on the wire)",
        ),
        BadCase(
            "cobs/group_overruns",
            bytes.fromhex("0a01020300"),
            BadFrameReason.COBS,
            "the first code byte (0x0a) announces 9 data bytes but only 3 follow",
        ),
        BadCase(
            "too_short/five_bytes",
            cobs.encode(bytes.fromhex("0113090300")) + DELIMITER,
            BadFrameReason.TOO_SHORT,
            "5 bytes after COBS decoding: less than header (4) + CRC (2)",
        ),
        BadCase(
            "too_short/one_byte",
            bytes.fromhex("0100"),
            BadFrameReason.TOO_SHORT,
            "the COBS group 0x01 alone decodes to zero bytes",
        ),
        BadCase(
            "too_long/259_bytes_no_delimiter",
            b"\x01" * (MAX_ENCODED + 1) + DELIMITER,
            BadFrameReason.TOO_LONG,
            f"{MAX_ENCODED + 1} bytes before a delimiter: longer than any encoded frame ({MAX_ENCODED})",
        ),
        BadCase(
            "too_long/257_byte_body",
            cobs.encode(bytes(257)) + DELIMITER,
            BadFrameReason.TOO_LONG,
            "valid COBS of 257 zero bytes: longer than header + 250-byte payload + CRC (256)",
        ),
        BadCase(
            "version/2",
            build_wire(Ack.MSG_ID, bytes([Arm.MSG_ID, 3]), seq=9, version=2),
            BadFrameReason.VERSION,
            "an Ack with protocol version 2 in the header (CRC correct)",
        ),
        BadCase(
            "version/0",
            build_wire(Heartbeat.MSG_ID, _payload(Heartbeat()), version=0),
            BadFrameReason.VERSION,
            "a Heartbeat with protocol version 0",
        ),
        BadCase(
            "unknown_id/0x7f",
            build_wire(0x7F, b""),
            BadFrameReason.UNKNOWN_ID,
            "message id 0x7f is not in the catalogue",
        ),
        BadCase(
            "length/ack_short",
            build_wire(Ack.MSG_ID, bytes([Arm.MSG_ID])),
            BadFrameReason.LENGTH,
            "an Ack payload of 1 byte (needs 2)",
        ),
        BadCase(
            "length/heartbeat_trailing",
            build_wire(Heartbeat.MSG_ID, _payload(Heartbeat()) + b"\x00"),
            BadFrameReason.LENGTH,
            "a Heartbeat with one trailing byte after its fields",
        ),
        BadCase(
            "length/arm_with_payload",
            build_wire(Arm.MSG_ID, b"\x01", flags=int(Flags.ACK_REQUESTED)),
            BadFrameReason.LENGTH,
            "Arm has no fields, this one carries a byte",
        ),
        BadCase(
            "length/text_past_end",
            build_wire(Log.MSG_ID, log[:-1]),
            BadFrameReason.LENGTH,
            "a Log whose text length byte (2) runs one byte past the payload's end",
        ),
        BadCase(
            "length/units_past_end",
            build_wire(ActuatorSetpoint.MSG_ID, setpoint[:-4]),
            BadFrameReason.LENGTH,
            "an ActuatorSetpoint announcing 1 unit with only 4 of its 8 bytes",
        ),
        BadCase(
            "field_range/enum",
            build_wire(SetMode.MSG_ID, b"\x07", flags=int(Flags.ACK_REQUESTED)),
            BadFrameReason.FIELD_RANGE,
            "SetMode.mode = 7 is not a ControlMode",
        ),
        BadCase(
            "field_range/nan",
            build_wire(ActuatorSetpoint.MSG_ID, bytes(nan_setpoint)),
            BadFrameReason.FIELD_RANGE,
            "ActuatorSetpoint.units[0].gimbal is NaN (0x7fc00000): no float field accepts NaN or infinity",
        ),
        BadCase(
            "field_range/rotor_speed",
            build_wire(ActuatorSetpoint.MSG_ID, bytes(big_rotor)),
            BadFrameReason.FIELD_RANGE,
            f"ActuatorSetpoint.units[0].rotor_speed = 3000.0 rad/s > {ROTOR_SPEED_LIMIT:g}",
        ),
        BadCase(
            "field_range/unit_count",
            build_wire(
                ActuatorSetpoint.MSG_ID, b"\x00" + bytes([MAX_UNITS + 1]) + bytes(8 * (MAX_UNITS + 1))
            ),
            BadFrameReason.FIELD_RANGE,
            f"ActuatorSetpoint with {MAX_UNITS + 1} units (at most {MAX_UNITS})",
        ),
        BadCase(
            "field_range/zero_units",
            build_wire(ActuatorSetpoint.MSG_ID, b"\x00\x00"),
            BadFrameReason.FIELD_RANGE,
            "ActuatorSetpoint with 0 units (at least 1)",
        ),
        BadCase(
            "field_range/pulse_width",
            build_wire(RawPulses.MSG_ID, bytes(pulses)),
            BadFrameReason.FIELD_RANGE,
            f"RawPulses.pulses_us[1] = 3000 us > {PULSE_MAX_US}",
        ),
        BadCase(
            "field_range/utf8",
            build_wire(Log.MSG_ID, log[:3] + b"\x02\xc3\x28"),
            BadFrameReason.FIELD_RANGE,
            "Log.text is not valid UTF-8 (0xc3 0x28)",
        ),
        BadCase(
            "field_range/text_too_long",
            build_wire(Hello.MSG_ID, b"\x01" + bytes(4) + b"\x19" + b"M" * 25 + b"\x00" * 5),
            BadFrameReason.FIELD_RANGE,
            "Hello.manufacturer of 25 bytes (at most 24)",
        ),
        BadCase(
            "field_range/protocol_version_0",
            build_wire(Hello.MSG_ID, b"\x00" + bytes(4) + bytes(6)),
            BadFrameReason.FIELD_RANGE,
            "Hello.protocol_version = 0 (1..255)",
        ),
        BadCase(
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
