"""Data: the byte streams of the vectors (frames, broken frames, garbage and idle delimiters with the
events a deframer must produce), and the inputs of the COBS and CRC primitives' cases."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..frame import BadFrameReason, encode_frame
from ..messages import Heartbeat


@dataclass(frozen=True)
class StreamCase:
    """``parts`` are ("good", frame vector name) | ("bad", bad vector name) | ("raw", bytes);
    ``events`` the expected events: ("frame", name) | ("bad", reason)."""

    name: str
    parts: tuple[tuple[str, Any], ...]
    events: tuple[tuple[str, str], ...]
    note: str


def stream_cases() -> list[StreamCase]:
    """Every stream, in file order; parts name vectors of :mod:`.frames` and :mod:`.bad_frames`."""
    crc = BadFrameReason.CRC.value
    return [
        StreamCase(
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
        StreamCase(
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
        StreamCase(
            "lost_delimiter_merges_two",
            (("raw", encode_frame(Heartbeat(time_ms=1), 1)[:-1]), ("good", "Ack/typical")),
            (("bad", crc),),
            "a frame whose delimiter was lost runs into the next one: one bad frame (the two bodies joined "
            "by a decoded 0x00 fail the CRC), then the stream is in sync again",
        ),
    ]


def cobs_cases() -> list[bytes]:
    """Decoded inputs of the COBS vectors, around the 254-byte block edge."""
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


def crc_cases() -> list[bytes]:
    """Inputs of the CRC vectors (``123456789`` is the standard check value)."""
    return [b"123456789", b"", b"\x00", b"\xff\xff", bytes(range(256))]
