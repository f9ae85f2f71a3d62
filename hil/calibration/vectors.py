"""Test vectors for other implementations of the calibration binary format and maps (the C firmware).

A JSON file with, for the default unit and every unit of a calibration file: the binary set (hex), and
conversions with their expected results and clamp flags; plus malformed sets, each with the location its
rejection must name. ``TOLERANCE`` is how far a float32 implementation of ``docs/calibration.md`` may
differ from these float64 reference results (``tests/test_calibration_float32.py`` checks a float32
transcription of the spec against it).
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from protocol.calibration import UnitCalibration, default_unit_calibration
from protocol.calibration.codec import HEADER, KNOT
from protocol.crc import crc16_ccitt_false
from protocol.errors import CalibrationError
from protocol.messages import GimbalMode

from .files import CalibrationSet
from .textfiles import write_atomic

FORMAT = "vscmg-hil calibration vectors"
VERSION = 1
TOLERANCE = {
    "pulse_us": 0.01,
    "rotor_speed_relative": 1e-5,
    "gimbal_rate_rad_s": 1e-5,
    "gimbal_angle_rad": 1e-5,
}
VOLTAGES = (0.5, 10.0, 11.1, 12.6)


def conversion_cases(cal: UnitCalibration) -> list[dict[str, Any]]:
    """Inputs spanning every branch of every map (below, inside and above each range; the deadbands)."""
    esc, rate = cal.rotor.esc, cal.gimbal_rate
    speeds = (-10.0, 0.0, 0.5, 10.0, 50.0, 100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 1e9)
    pulses = sorted({900.0, esc.low_us, esc.start_us, esc.start_us + 0.25, *range(1100, 2001, 100), 2100.0})
    lo, hi = rate.dead_zone_us
    gimbal_pulses = sorted({900.0, *range(1000, 2001, 50), lo - 0.5, lo, rate.hold_us, hi, hi + 0.5, 2100.0})
    rates = (-20.0, -2.0, -1.0, -0.4, -0.01, 0.0, 0.01, 0.4, 1.0, 2.0, 20.0)
    angles = (-3.0, -1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 3.0)
    cases: list[dict[str, Any]] = []

    def add(fn: str, inputs: tuple[float, ...], call: Callable[..., Any]) -> None:
        c = call(*inputs)
        cases.append({"fn": fn, "in": list(inputs), "out": c.value, "clamp": c.clamp.name})

    for v in VOLTAGES:
        for w in speeds:
            add("rotor_pulse_us", (w, v), cal.rotor_pulse_us)
        for p in pulses:
            add("rotor_speed", (p, v), cal.rotor_speed)
    for mode, values in ((GimbalMode.RATE, rates), (GimbalMode.ANGLE, angles)):
        for x in values:
            add("gimbal_pulse_us", (x, int(mode)), lambda x, m: cal.gimbal_pulse_us(x, GimbalMode(m)))
        for p in gimbal_pulses:
            add("gimbal_value", (p, int(mode)), lambda p, m: cal.gimbal_value(p, GimbalMode(m)))
    return cases


@dataclass(frozen=True)
class Malformed:
    what: str
    data: bytes
    where: str  # a substring the rejection (location or reason) must contain


def malformed_sets(good: bytes) -> list[Malformed]:
    """Damaged variants of ``good``, each breaking one rule; ``where`` is what the error must name."""
    n = len(good)
    counts = HEADER.unpack_from(good)[-4:]
    table3 = HEADER.size + KNOT.size * sum(counts[:3])  # first knot of the angle table
    out = [
        Malformed("truncated", good[:20], "truncated"),
        Malformed("bad magic", _patch(good, 0, b"XC"), "byte 0"),
        Malformed("unknown version", _patch(good, 2, b"\x02"), "byte 2"),
        Malformed("reserved flags set", _patch(good, 3, b"\x01"), "byte 3"),
        Malformed("one-knot table", _patch(good, 25, b"\x01"), "byte 25"),
        Malformed("trailing byte", _recrc(good[:-2] + b"\x00"), "length"),
        Malformed("CRC damaged", _patch(good, n - 2, bytes([good[-2] ^ 0x01])), f"byte {n - 2}"),
        Malformed(
            "bit flip in a knot", _patch(good, table3 + 5, bytes([good[table3 + 5] ^ 0x10])), f"byte {n - 2}"
        ),
        Malformed(
            "NaN knot value",
            _recrc(_patch(good, table3 + 4, struct.pack("<f", float("nan")))),
            "gimbal_angle",
        ),
        Malformed(
            "angle table not monotone",
            _recrc(_patch(good, table3 + KNOT.size + 4, good[table3 + 4 : table3 + 8])),
            "gimbal_angle",
        ),
        Malformed(
            "slope beyond 3x the secant", _recrc(_patch(good, table3 + 8, struct.pack("<f", 1.0))), "slope[0]"
        ),
        Malformed(
            "hold pulse outside the dead zone", _recrc(_patch(good, 20, struct.pack("<f", 2400.0))), "hold_us"
        ),
        Malformed(
            "ESC endpoints reversed", _recrc(_patch(good, 4, struct.pack("<ff", 2000.0, 1000.0))), "esc"
        ),
        Malformed("KV of zero", _recrc(_patch(good, 16, struct.pack("<f", 0.0))), "kv_rad_s_per_v"),
    ]
    for m in out:  # each must really be rejected, at the stated place
        try:
            UnitCalibration.from_bytes(m.data, source="vector")
        except CalibrationError as exc:
            if m.where not in str(exc):
                raise AssertionError(f"{m.what}: {exc} does not name {m.where!r}") from exc
        else:
            raise AssertionError(f"{m.what}: accepted")
    return out


def _patch(data: bytes, offset: int, new: bytes) -> bytes:
    return data[:offset] + new + data[offset + len(new) :]


def _recrc(data: bytes) -> bytes:
    """``data`` with its trailing CRC recomputed, so only the damage inside is wrong."""
    return data[:-2] + struct.pack("<H", crc16_ccitt_false(data[:-2]))


def build_vectors(cset: CalibrationSet, source: str = "") -> dict[str, Any]:
    units = [("default", default_unit_calibration())] + [
        (f"{source} unit {u.index} ({u.name})", u.calibration) for u in cset.units
    ]
    good = default_unit_calibration().to_bytes()
    return {
        "format": FORMAT,
        "version": VERSION,
        "spec": "docs/calibration.md",
        "tolerance": TOLERANCE,
        "sets": [
            {
                "name": name,
                "size": len(data := cal.to_bytes()),
                "crc": crc16_ccitt_false(data),
                "hex": data.hex(),
                "cases": conversion_cases(cal),
            }
            for name, cal in units
        ],
        "malformed": [{"what": m.what, "hex": m.data.hex(), "where": m.where} for m in malformed_sets(good)],
    }


def dumps_vectors(doc: dict[str, Any]) -> str:
    """JSON with one conversion case or malformed set per line (diffable, and a third the size)."""
    sets = [
        "  {"
        + ", ".join(f"{json.dumps(k)}: {json.dumps(v)}" for k, v in s.items() if k != "cases")
        + ', "cases": [\n'
        + ",\n".join("    " + json.dumps(c) for c in s["cases"])
        + "\n  ]}"
        for s in doc["sets"]
    ]
    head = {k: v for k, v in doc.items() if k not in ("sets", "malformed")}
    return (
        json.dumps(head)[:-1]
        + ',\n "sets": [\n'
        + ",\n".join(sets)
        + '\n ],\n "malformed": [\n'
        + ",\n".join("  " + json.dumps(m) for m in doc["malformed"])
        + "\n ]}\n"
    )


def write_vectors(cset: CalibrationSet, path: str | os.PathLike[str], source: str = "") -> Path:
    return write_atomic(path, dumps_vectors(build_vectors(cset, source)))
