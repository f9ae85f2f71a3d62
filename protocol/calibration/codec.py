"""The binary calibration set: what ``CALIBRATION`` transfers carry and the board keeps in EEPROM.

Version 1, little-endian, IEEE-754 binary32 floats (``docs/calibration.md`` is the byte-level spec)::

    offset  size   type      field
    0       2      u8[2]     magic "VC" (0x56 0x43)
    2       1      u8        format version (1)
    3       1      u8        flags, reserved: 0
    4       4      f32       esc.low_us            calibrated low endpoint = minimum throttle (µs)
    8       4      f32       esc.high_us           calibrated high endpoint = full throttle (µs)
    12      4      f32       esc.deadband_us       throttle stays 0 up to low_us + deadband_us (µs)
    16      4      f32       rotor.kv_rad_s_per_v  no-load speed at full throttle per battery volt
    20      4      f32       gimbal_rate.hold_us   the pulse that holds the gimbal still (µs)
    24      1      u8        n0  knots of table 0, the rotor throttle curve  (2..16 each)
    25      1      u8        n1  knots of table 1, gimbal rate below the dead zone
    26      1      u8        n2  knots of table 2, gimbal rate above the dead zone
    27      1      u8        n3  knots of table 3, gimbal angle
    28      12·n0  knot[n0]  table 0: x = throttle 0..1, y = fraction of KV·V, m = dy/dx
    ...     12·n1  knot[n1]  table 1: x = pulse µs, y = rad/s, m = (rad/s)/µs; ends at y = 0
    ...     12·n2  knot[n2]  table 2: x = pulse µs, y = rad/s, m = (rad/s)/µs; starts at y = 0
    ...     12·n3  knot[n3]  table 3: x = pulse µs, y = rad, m = rad/µs
    28+12n  2      u16       CRC-16/CCITT-FALSE of bytes 0 .. 27+12n             (n = n0 + n1 + n2 + n3)

    knot = { f32 x; f32 y; f32 m; }   (12 bytes)

The CRC lets the board check its EEPROM copy at boot; transfers carry a CRC of their own.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

from ..crc import crc16_ccitt_false
from ..errors import CalibrationError
from .checks import within
from .cubic import MAX_KNOTS, MonotoneCubic
from .maps import EscThrottleMap, GimbalAngleMap, GimbalRateMap, RotorSpeedMap

MAGIC = b"VC"
FORMAT_VERSION = 1
HEADER = struct.Struct("<2sBBfffffBBBB")
KNOT = struct.Struct("<fff")
CRC = struct.Struct("<H")
TABLES = ("rotor_curve", "gimbal_rate_lower", "gimbal_rate_upper", "gimbal_angle")
MIN_SIZE = HEADER.size + len(TABLES) * 2 * KNOT.size + CRC.size
MAX_SIZE = HEADER.size + len(TABLES) * MAX_KNOTS * KNOT.size + CRC.size


def encode_maps(rotor: RotorSpeedMap, rate: GimbalRateMap, angle: GimbalAngleMap) -> bytes:
    """The version-1 bytes of one unit's maps."""
    tables = (rotor.curve, rate.lower, rate.upper, angle.curve)
    esc = rotor.esc
    out = bytearray(
        HEADER.pack(
            MAGIC,
            FORMAT_VERSION,
            0,
            esc.low_us,
            esc.high_us,
            esc.deadband_us,
            rotor.kv_rad_s_per_v,
            rate.hold_us,
            *(len(t.x) for t in tables),
        )
    )
    for t in tables:
        for knot in zip(t.x, t.y, t.slopes, strict=True):
            out += KNOT.pack(*knot)
    out += CRC.pack(crc16_ccitt_false(bytes(out)))
    return bytes(out)


def decode_maps(data: bytes, source: str = "") -> tuple[RotorSpeedMap, GimbalRateMap, GimbalAngleMap]:
    """Parse and validate version-1 bytes. Raises :class:`CalibrationError` whose ``where`` starts with
    ``source`` and names the field (and its byte offset) for anything malformed."""
    where = source or "calibration set"
    data = bytes(data)
    if len(data) < HEADER.size + CRC.size:
        raise CalibrationError(f"truncated: {len(data)} bytes, a set has at least {MIN_SIZE}", where)
    magic, version, flags, low, high, dead, kv, hold, *counts = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise CalibrationError(f"magic {magic!r} is not {MAGIC!r}: not a calibration set", f"{where}: byte 0")
    if version != FORMAT_VERSION:
        raise CalibrationError(
            f"format version {version} is not supported (this reader knows {FORMAT_VERSION})",
            f"{where}: byte 2",
        )
    if flags:
        raise CalibrationError(f"reserved flags {flags:#04x} must be 0", f"{where}: byte 3")
    for i, (name, n) in enumerate(zip(TABLES, counts, strict=True)):
        if not 2 <= n <= MAX_KNOTS:
            raise CalibrationError(
                f"{n} knots in {name}; a table has 2 to {MAX_KNOTS}", f"{where}: byte {24 + i}"
            )
    size = HEADER.size + KNOT.size * sum(counts) + CRC.size
    if len(data) != size:
        raise CalibrationError(
            f"{len(data)} bytes, but its knot counts {tuple(counts)} make a {size}-byte set",
            f"{where}: length",
        )
    (crc,) = CRC.unpack_from(data, size - CRC.size)
    want = crc16_ccitt_false(data[: size - CRC.size])
    if crc != want:
        raise CalibrationError(
            f"CRC {crc:#06x} != {want:#06x} computed: damaged", f"{where}: byte {size - CRC.size}"
        )
    tables = []
    offset = HEADER.size
    for name, n in zip(TABLES, counts, strict=True):
        knots = [KNOT.unpack_from(data, offset + KNOT.size * k) for k in range(n)]
        with within(f"{where}: {name} (bytes {offset}-{offset + KNOT.size * n - 1})"):
            tables.append(MonotoneCubic(*_columns(knots)))
        offset += KNOT.size * n
    with within(f"{where}: esc (bytes 4-15)"):
        esc = EscThrottleMap(low, high, dead)
    with within(f"{where}: rotor"):
        rotor = RotorSpeedMap(esc, kv, tables[0])
    with within(f"{where}: gimbal_rate"):
        rate = GimbalRateMap(hold, tables[1], tables[2])
    with within(f"{where}: gimbal_angle"):
        angle = GimbalAngleMap(tables[3])
    return rotor, rate, angle


def _columns(knots: Sequence[tuple[float, float, float]]) -> tuple[tuple[float, ...], ...]:
    xs, ys, ms = zip(*knots, strict=True)
    return xs, ys, ms
