"""Generate the firmware's definitions from the Python sources of truth.

``python -m firmware_sim.avr.codegen`` writes

* ``firmware/include/protocol_gen.h`` and ``firmware/src/protocol_gen.c`` from ``protocol/messages.py``:
  message ids, enums, C structs for every message and record, range macros, the wire field tables walked
  by ``firmware/src/wire.c``, ``PROTOCOL_VERSION``, ``SCHEMA_HASH``, the board's log codes and the
  default calibration set (``protocol.calibration.default_unit_calibration()``) the firmware boots with;
* ``firmware/include/board_gen.h`` from ``firmware_sim.board.config`` and ``firmware_sim.avr.eeprom``: the
  EEPROM layout (configuration block offsets, calibration slots), the defaults of ``BoardConfig`` the
  firmware falls back on, the identity strings, and the LiPo discharge curve (:mod:`.codegen_board`).

The protocol files are generated here; C literals shared by both are in :mod:`.c_literals`.

``--check`` exits 1 if the committed files differ from what the sources generate now (the test suite
runs the same comparison), so the Python and C ends cannot drift apart silently.
"""

from __future__ import annotations

import argparse
import enum
import re
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from protocol import messages as catalogue
from protocol.fields import Array, Blob, Enum8, Layout, Scalar, Text, layout_of
from protocol.frame import HEADER_SIZE, MAX_ENCODED, MAX_FRAME, MAX_PAYLOAD, BadFrameReason

from .c_literals import BANNER, bytes_init, c_float, c_int
from .codegen_board import generate_board
from .paths import FIRMWARE_DIR

HEADER_PATH = FIRMWARE_DIR / "include" / "protocol_gen.h"
SOURCE_PATH = FIRMWARE_DIR / "src" / "protocol_gen.c"
BOARD_PATH = FIRMWARE_DIR / "include" / "board_gen.h"

_KIND = {
    "B": "WIRE_U8",
    "H": "WIRE_U16",
    "I": "WIRE_U32",
    "b": "WIRE_I8",
    "h": "WIRE_I16",
    "i": "WIRE_I32",
    "f": "WIRE_F32",
}
_CTYPE = {
    "B": "uint8_t",
    "H": "uint16_t",
    "I": "uint32_t",
    "b": "int8_t",
    "h": "int16_t",
    "i": "int32_t",
    "f": "float",
}


def snake(name: str) -> str:
    """``HelloReply`` → ``hello_reply``."""
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


def _enum_mask(cls: Any) -> int:
    values = [int(m) for m in cls]
    if max(values) >= 32 or min(values) < 0:
        raise ValueError(f"{cls.__name__}: enum values must lie in 0..31 for the C bit mask")
    return sum(1 << v for v in values)


# --------------------------------------------------------------------------- header pieces
def _enums() -> list[Any]:
    """Every IntEnum/IntFlag of the catalogue module, in definition order."""
    found = []
    for value in vars(catalogue).values():
        if (
            isinstance(value, type)
            and issubclass(value, enum.IntEnum | enum.IntFlag)
            and (value.__module__ == catalogue.__name__)
        ):
            found.append(value)
    return found


def _enum_block(cls: Any, prefix: str) -> str:
    lines = [
        f"/* {cls.__name__}: {(cls.__doc__ or '').strip().splitlines()[0]} */"
        if cls.__doc__
        else f"/* {cls.__name__} */"
    ]
    lines.append("enum {")
    for m in cls:
        if isinstance(m, enum.Flag) and m.value == 0 and m.name == "NONE":
            continue
        lines.append(
            f"    {prefix}_{m.name} = {int(m):#x},"
            if issubclass(cls, enum.IntFlag)
            else f"    {prefix}_{m.name} = {int(m)},"
        )
    lines.append("};")
    if not issubclass(cls, enum.IntFlag):
        by_value = {int(m): m.name for m in cls}
        names = "".join(f"{by_value.get(v, '?')}\\0" for v in range(max(by_value) + 1))
        lines.append(f'#define {prefix}_NAMES "{names}" /* indexed by value, for logs */')
    return "\n".join(lines)


@dataclass
class _Struct:
    """One generated C struct and its field table."""

    py_name: str
    c_name: str  # snake
    layout: Layout


def _records() -> list[type]:
    seen: list[type] = []
    for cls in catalogue.CATALOGUE:
        for _, codec in layout_of(cls).fields:
            if isinstance(codec, Array) and not isinstance(codec.item, Scalar) and codec.item not in seen:
                seen.append(codec.item)
    return seen


def _c_member(name: str, codec: object) -> str:
    if isinstance(codec, Scalar):
        kind = "enum8" if isinstance(codec, Enum8) else codec.type_name()
        return f"    {_CTYPE[codec.fmt]} {name}; /* {kind} {_range_doc(codec)} */"
    if isinstance(codec, Text):
        body = f"        uint8_t len;\n        char s[{codec.max_len}];"
        return f"    struct {{\n{body}\n    }} {name}; /* UTF-8 */"
    if isinstance(codec, Blob):
        return f"    struct {{\n        uint8_t len;\n        uint8_t b[{codec.max_len}];\n    }} {name};"
    assert isinstance(codec, Array)
    item = codec.item
    ctype = _CTYPE[item.fmt] if isinstance(item, Scalar) else f"{snake(item.__name__)}_t"
    return (
        f"    struct {{\n        uint8_t count; /* {codec.min_count}..{codec.max_count} */\n"
        f"        {ctype} items[{codec.max_count}];\n    }} {name};"
    )


def _range_doc(codec: Scalar) -> str:
    if isinstance(codec, Enum8):
        return codec.enum_cls.__name__
    unit = f" {codec.unit}" if codec.unit else ""
    return f"[{codec.lo:g}, {codec.hi:g}]{unit}"


def _struct_block(s: _Struct, doc: str) -> str:
    members = [_c_member(n, c) for n, c in s.layout.fields]
    if not members:
        members = ["    uint8_t unused_; /* no fields on the wire */"]
    return f"/* {s.py_name}: {doc} */\ntypedef struct {{\n" + "\n".join(members) + f"\n}} {s.c_name}_t;"


def _range_macros(prefix: str, layout: Layout) -> list[str]:
    out = []
    for name, codec in layout.fields:
        scalar = (
            codec
            if isinstance(codec, Scalar)
            else (codec.item if isinstance(codec, Array) and isinstance(codec.item, Scalar) else None)
        )
        if isinstance(codec, (Text, Blob)):
            out.append(f"#define {prefix}_{name.upper()}_MAX_LEN {codec.max_len}u")
        if isinstance(codec, Array):
            out.append(f"#define {prefix}_{name.upper()}_MIN_COUNT {codec.min_count}u")
            out.append(f"#define {prefix}_{name.upper()}_MAX_COUNT {codec.max_count}u")
        if scalar is None or isinstance(scalar, Enum8):
            continue
        if scalar.fmt == "f":
            lo, hi = c_float(float(scalar.lo)), c_float(float(scalar.hi))
        else:
            signed = scalar.fmt in "bhi"
            lo, hi = c_int(scalar.lo, signed), c_int(scalar.hi, signed)
        out.append(f"#define {prefix}_{name.upper()}_MIN {lo}")
        out.append(f"#define {prefix}_{name.upper()}_MAX {hi}")
    return out


# --------------------------------------------------------------------------- field tables
def _range_init(scalar: Scalar) -> str:
    if isinstance(scalar, Enum8):
        return f"{{.mask = {_enum_mask(scalar.enum_cls):#x}UL}}"
    if scalar.fmt == "f":
        return f"{{.f = {{{c_float(float(scalar.lo))}, {c_float(float(scalar.hi))}}}}}"
    if scalar.fmt in "bhi":
        return f"{{.i = {{{c_int(scalar.lo, True)}, {c_int(scalar.hi, True)}}}}}"
    return f"{{.u = {{{c_int(scalar.lo, False)}, {c_int(scalar.hi, False)}}}}}"


def _scalar_kind(scalar: Scalar) -> str:
    return "WIRE_ENUM8" if isinstance(scalar, Enum8) else _KIND[scalar.fmt]


def _run_lengths(layout: Layout) -> list[int]:
    """Wire bytes of the run of consecutive scalars starting at each field (0 inside a run)."""
    runs = [0] * len(layout.fields)
    start = None
    for i, (_, codec) in enumerate(layout.fields):
        if isinstance(codec, Scalar):
            if start is None:
                start = i
            runs[start] += codec.size
        else:
            start = None
    return runs


def _field_table(s: _Struct, records: Sequence[type]) -> str:
    t = f"{s.c_name}_t"
    rows = []
    for (name, codec), run in zip(s.layout.fields, _run_lengths(s.layout), strict=True):
        if isinstance(codec, Scalar):
            rows.append(
                f"    {{.kind = {_scalar_kind(codec)}, .run_len = {run}, .offset = offsetof({t}, {name}), "
                f".range = {_range_init(codec)}}},"
            )
        elif isinstance(codec, (Text, Blob)):
            kind, data = ("WIRE_TEXT", "s") if isinstance(codec, Text) else ("WIRE_BLOB", "b")
            rows.append(
                f"    {{.kind = {kind}, .offset = offsetof({t}, {name}.len), "
                f".data_offset = offsetof({t}, {name}.{data}), .max_count = {codec.max_len}}},"
            )
        else:
            assert isinstance(codec, Array)
            common = (
                f".offset = offsetof({t}, {name}.count), .data_offset = offsetof({t}, {name}.items), "
                f".elem_size = sizeof((({t} *)0)->{name}.items[0]), .min_count = {codec.min_count}, "
                f".max_count = {codec.max_count}"
            )
            if isinstance(codec.item, Scalar):
                rows.append(
                    f"    {{.kind = WIRE_ARRAY, .elem = {_scalar_kind(codec.item)}, {common}, "
                    f".range = {_range_init(codec.item)}}},"
                )
            else:
                rows.append(
                    f"    {{.kind = WIRE_ARRAY, .elem = WIRE_RECORD, .record = "
                    f"{records.index(codec.item)}, {common}}},"
                )
    if not rows:
        return f"static const wire_field_t {s.c_name}_fields[1] FLASH = {{{{0}}}};"
    return f"static const wire_field_t {s.c_name}_fields[] FLASH = {{\n" + "\n".join(rows) + "\n};"


# --------------------------------------------------------------------------- the files
def _board_log_codes() -> type[enum.IntEnum]:
    from firmware_sim.board import LogCode

    return LogCode


def _default_calibration() -> bytes:
    from protocol.calibration import default_unit_calibration

    data: bytes = default_unit_calibration().to_bytes()
    return data


def generate() -> tuple[str, str]:
    """(header text, source text) for the current catalogue."""
    messages = [
        _Struct(c.__name__, snake(c.__name__), layout_of(c))
        for c in sorted(catalogue.CATALOGUE, key=lambda c: c.MSG_ID)
    ]
    recs = _records()
    records = [_Struct(r.__name__, snake(r.__name__), layout_of(r)) for r in recs]
    cal = _default_calibration()

    h: list[str] = [
        BANNER,
        "#ifndef PROTOCOL_GEN_H",
        "#define PROTOCOL_GEN_H",
        "",
        "#include <stddef.h>",
        "#include <stdint.h>",
        "",
        '#include "wire.h"',
        "",
    ]
    h += [
        f"#define PROTOCOL_VERSION {catalogue.PROTOCOL_VERSION}u",
        f"#define SCHEMA_HASH {catalogue.SCHEMA_HASH:#010x}UL /* SHA-256 of the catalogue's schema text */",
        f"#define FRAME_HEADER_SIZE {HEADER_SIZE}u",
        "#define FRAME_CRC_SIZE 2u",
        f"#define FRAME_MAX_PAYLOAD {MAX_PAYLOAD}u",
        f"#define FRAME_MAX_FRAME {MAX_FRAME}u /* header + payload + CRC */",
        f"#define FRAME_MAX_ENCODED {MAX_ENCODED}u /* COBS-encoded, without the delimiter */",
        f"#define MAX_UNITS {catalogue.MAX_UNITS}u",
        f"#define MAX_CHANNELS {catalogue.MAX_CHANNELS}u",
        f"#define MAX_CALIBRATION_CHUNK {catalogue.MAX_CALIBRATION_CHUNK}u",
        f"#define GIMBAL_RATE_LIMIT {c_float(catalogue.GIMBAL_RATE_LIMIT)}",
        f"#define GIMBAL_ANGLE_LIMIT {c_float(catalogue.GIMBAL_ANGLE_LIMIT)}",
        f"#define ROTOR_SPEED_LIMIT {c_float(catalogue.ROTOR_SPEED_LIMIT)}",
        f"#define PULSE_MIN_US {catalogue.PULSE_MIN_US}u",
        f"#define PULSE_MAX_US {catalogue.PULSE_MAX_US}u",
        f"#define ESC_CALIBRATION_CONFIRM {catalogue.ESC_CALIBRATION_CONFIRM:#010x}UL /* EscCalibrate */",
        "",
    ]
    for cls in _enums():
        h += [_enum_block(cls, snake(cls.__name__).upper()), ""]
    h += [
        "/* BadFrameReason (protocol/frame.py): why a delimited chunk was not a valid frame; 0 = none */",
        "enum {",
    ]
    h += [f"    BAD_FRAME_{r.name} = {i}," for i, r in enumerate(BadFrameReason, start=1)]
    h += ["};", f"#define BAD_FRAME_REASONS {len(BadFrameReason)}u", ""]
    h += [_enum_block(_board_log_codes(), "LOG_CODE"), ""]

    for r in records:
        h += [_struct_block(r, "record"), ""]
    h += [f"enum {{ RECORD_{r.c_name.upper()} = {i} }};" for i, r in enumerate(records)]
    h += [""]
    for m, cls in zip(messages, sorted(catalogue.CATALOGUE, key=lambda c: c.MSG_ID), strict=True):
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        prefix = m.c_name.upper()
        h += [
            f"#define MSG_{prefix} {cls.MSG_ID:#04x}u",
            f"#define MSG_{prefix}_RELIABLE {int(cls.RELIABLE)}",
        ]
        h += _range_macros(prefix, m.layout)
        h += [_struct_block(m, doc), ""]
    for r in records:
        h += _range_macros(r.c_name.upper(), r.layout)
    h += ["", "/* Any message, for decoding into one buffer. */", "typedef union {"]
    h += [f"    {m.c_name}_t {m.c_name};" for m in messages]
    h += ["} msg_any_t;", ""]
    h += [
        "/* Layouts (in flash on the AVR): records by RECORD_* index; messages by id. */",
        "extern const wire_layout_t wire_records[];",
    ]
    h += [f"extern const wire_layout_t WIRE_LAYOUT_{m.c_name.upper()};" for m in messages]
    h += [
        "",
        "/* The layout of message `msg_id`, or NULL for an id outside the catalogue. */",
        "const wire_layout_t *wire_layout_for(uint8_t msg_id);",
        "/* 1 if message `msg_id` is reliable (answered with Ack/Nack), else 0. */",
        "uint8_t msg_is_reliable(uint8_t msg_id);",
        "",
        "/* Serialised default calibration set (protocol.calibration.default_unit_calibration()). */",
        f"#define DEFAULT_CALIBRATION_LEN {len(cal)}u",
        "extern const uint8_t DEFAULT_CALIBRATION[DEFAULT_CALIBRATION_LEN];",
        "",
        "#endif /* PROTOCOL_GEN_H */",
        "",
    ]

    c: list[str] = [BANNER, '#include "protocol_gen.h"', ""]
    for s in records + messages:
        c += [_field_table(s, recs), ""]
    c += ["const wire_layout_t wire_records[] FLASH = {"]
    c += [f"    {{{r.c_name}_fields, {len(r.layout.fields)}, sizeof({r.c_name}_t)}}," for r in records]
    c += ["};", ""]
    for m in messages:
        c += [
            f"const wire_layout_t WIRE_LAYOUT_{m.c_name.upper()} FLASH = "
            f"{{{m.c_name}_fields, {len(m.layout.fields)}, sizeof({m.c_name}_t)}};"
        ]
    c += ["", "const wire_layout_t *wire_layout_for(uint8_t msg_id)", "{", "    switch (msg_id) {"]
    for m in messages:
        c += [f"    case MSG_{m.c_name.upper()}:", f"        return &WIRE_LAYOUT_{m.c_name.upper()};"]
    c += ["    default:", "        return NULL;", "    }", "}", ""]
    c += ["uint8_t msg_is_reliable(uint8_t msg_id)", "{", "    switch (msg_id) {"]
    c += [
        f"    case MSG_{m.c_name.upper()}:"
        for m, cls in zip(messages, sorted(catalogue.CATALOGUE, key=lambda c: c.MSG_ID), strict=True)
        if cls.RELIABLE
    ]
    c += ["        return 1;", "    default:", "        return 0;", "    }", "}", ""]
    c += ["const uint8_t DEFAULT_CALIBRATION[DEFAULT_CALIBRATION_LEN] FLASH = {", bytes_init(cal), "};", ""]
    return "\n".join(h), "\n".join(c)


def _outputs() -> list[tuple[Path, str]]:
    header, source = generate()
    return [(HEADER_PATH, header), (SOURCE_PATH, source), (BOARD_PATH, generate_board())]


def stale_files() -> list[Path]:
    """Generated files whose committed text differs from what the sources generate now."""
    return [p for p, text in _outputs() if not p.exists() or p.read_text(encoding="utf-8") != text]


def write() -> list[Path]:
    """Write the generated files; returns those that changed."""
    changed = []
    for path, text in _outputs():
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
            changed.append(path)
    return changed


def main(argv: Iterable[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m firmware_sim.avr.codegen",
        description="Generate the firmware's protocol header and field tables from protocol/messages.py.",
        epilog="examples:\n"
        "  python -m firmware_sim.avr.codegen          regenerate after changing the catalogue\n"
        "  python -m firmware_sim.avr.codegen --check  exit 1 if the committed files are stale",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--check", action="store_true", help="only compare; exit 1 if a file is stale")
    args = parser.parse_args(None if argv is None else list(argv))
    if args.check:
        stale = stale_files()
        for p in stale:
            sys.stderr.write(f"stale: {p} (run python -m firmware_sim.avr.codegen)\n")
        return 1 if stale else 0
    for p in write():
        sys.stdout.write(f"wrote {p}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
