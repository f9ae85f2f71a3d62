"""``python -m protocol``: regenerate (or check) the files derived from the message catalogue.

The codec in ``protocol/`` is sans-IO; this script is the one place that writes its derived files:

* ``vectors``: ``fixtures/protocol_vectors.json``, the canonical test vectors (:mod:`protocol.vectors`);
* ``doc``: the byte tables between the markers in ``docs/protocol.md``, rendered from the catalogue by
  :func:`render_tables` (so the specification cannot drift from the code).

``--check`` exits 1 if the file on disk differs from what the code generates now (CI-friendly).
"""

from __future__ import annotations

import argparse
import enum
import inspect
import sys
from pathlib import Path

from .errors import InputFormatError
from .fields import Array, Blob, Enum8, Scalar, Text, layout_of
from .frame import HEADER_SIZE, MAX_ENCODED
from .messages import CATALOGUE, SCHEMA_HASH, FaultFlag, Flags

ROOT = Path(__file__).resolve().parent.parent
VECTORS = ROOT / "fixtures" / "protocol_vectors.json"
DOC = ROOT / "docs" / "protocol.md"

EXAMPLES = """examples:
  python -m protocol vectors --write                  # regenerate fixtures/protocol_vectors.json
  python -m protocol vectors --check                  # exit 1 if the committed vectors are stale
  python -m protocol vectors --write /tmp/v.json      # write them elsewhere
  python -m protocol doc --write                      # refresh the byte tables in docs/protocol.md
  python -m protocol doc --check
"""


BEGIN = "<!-- BEGIN GENERATED: python -m protocol doc --write (do not edit by hand) -->"
END = "<!-- END GENERATED -->"


# =========================================================================== byte tables
def render_tables() -> str:
    """Markdown of the catalogue: summary, one byte table per message and record, enums and bit flags."""
    from .vectors import payload_size_range

    out = ["### Message summary", ""]
    out += [
        "| id | message | reliable | payload bytes | wire bytes (max) | what |",
        "|---|---|---|---|---|---|",
    ]
    messages = sorted(CATALOGUE, key=lambda c: c.MSG_ID)
    for cls in messages:
        lo, hi = payload_size_range(cls)
        wire = _wire_len(hi)
        reliable = "yes" if cls.RELIABLE else "no"
        cells = (f"0x{cls.MSG_ID:02x}", cls.__name__, reliable, _span(lo, hi), str(wire), _summary(cls))
        out.append("| " + " | ".join(cells) + " |")
    out += ["", f"Schema hash of this catalogue: `0x{SCHEMA_HASH:08x}`.", ""]
    records: list[type] = []
    enums: list[type[enum.IntEnum]] = []
    for cls in messages:
        size = _span(*payload_size_range(cls))
        out += [f"### 0x{cls.MSG_ID:02x} {cls.__name__} (payload {size} bytes)", "", _summary(cls), ""]
        out += _field_table(cls, records, enums)
    for rec in records:
        out += [f"### Record {rec.__name__} ({payload_size_range(rec)[1]} bytes)", "", _summary(rec), ""]
        out += _field_table(rec, records, enums)
    for e in enums:
        out += [f"### Enum {e.__name__} (u8)", "", _summary(e), "", "| value | name |", "|---|---|"]
        out += [f"| {int(m)} | {m.name} |" for m in e]
        out.append("")
    for flag, where in ((Flags, "the frame header's `flags` byte"), (FaultFlag, "`Telemetry.faults` (u16)")):
        out += [f"### Bits {flag.__name__}", "", f"Bits of {where}; unlisted bits are 0.", ""]
        out += ["| bit | mask | name |", "|---|---|---|"]
        out += [f"| {m.value.bit_length() - 1} | 0x{m.value:04x} | {m.name} |" for m in flag if m.value]
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def _span(lo: int, hi: int) -> str:
    return str(lo) if lo == hi else f"{lo}..{hi}"


def _wire_len(payload: int) -> int:
    """Longest wire form of a frame with ``payload`` bytes: COBS + delimiter."""
    body = HEADER_SIZE + payload + 2
    return min(body + body // 254 + 1, MAX_ENCODED) + 1


def _summary(obj: type) -> str:
    doc = inspect.cleandoc(obj.__dict__.get("__doc__") or "")  # the class's own docstring, not a base's
    return " ".join(doc.split("\n\n")[0].split()).replace("``", "`").replace("|", "\\|")


def _field_table(cls: type, records: list[type], enums: list[type[enum.IntEnum]]) -> list[str]:
    fields = layout_of(cls).fields
    if not fields:
        return ["No fields: the payload is empty.", ""]
    rows = ["| offset | size | field | type | unit | range |", "|---|---|---|---|---|---|"]
    offset: int | None = 0
    for name, codec in fields:
        if isinstance(codec, Enum8) and codec.enum_cls not in enums:
            enums.append(codec.enum_cls)
        if isinstance(codec, Array) and not isinstance(codec.item, Scalar) and codec.item not in records:
            records.append(codec.item)
        size, type_, unit, range_ = _describe(codec)
        rows.append(
            f"| {'…' if offset is None else offset} | {size} | `{name}` | {type_} | {unit} | {range_} |"
        )
        offset = offset + codec.size if offset is not None and isinstance(codec, Scalar) else None
    return rows + [""]


def _describe(codec: object) -> tuple[str, str, str, str]:
    """(size, type, unit, range) cells of one field."""
    if isinstance(codec, Enum8):
        return "1", f"u8 enum {codec.enum_cls.__name__}", "", f"{codec.enum_cls.__name__} values"
    if isinstance(codec, Scalar):
        if codec.fmt == "f":
            range_ = f"±{codec.hi:g}" if codec.lo == -codec.hi else f"{codec.lo:g}..{codec.hi:g}"
            range_ += ", finite"
        else:
            range_ = f"{int(codec.lo)}..{int(codec.hi)}"
        return str(codec.size), codec.type_name(), codec.unit, range_
    if isinstance(codec, Text):
        return "1+n", "u8 n, then n bytes UTF-8", "", f"n ≤ {codec.max_len}"
    if isinstance(codec, Blob):
        return "1+n", "u8 n, then n bytes", "", f"n ≤ {codec.max_len}"
    assert isinstance(codec, Array)
    item = codec.item
    if isinstance(item, Scalar):
        size, type_, unit, range_ = _describe(item)
        return (
            f"1+{size}n",
            f"u8 n, then n × {type_}",
            unit,
            f"n {codec.min_count}..{codec.max_count}; {range_}",
        )
    size = str(layout_of(item).fixed_size)
    return f"1+{size}n", f"u8 n, then n × {item.__name__}", "", f"n {codec.min_count}..{codec.max_count}"


def replace_generated(text: str, where: str = "docs/protocol.md") -> str:
    """``text`` with the part between :data:`BEGIN` and :data:`END` replaced by :func:`render_tables`."""
    start = text.find(BEGIN)
    stop = text.find(END)
    if start < 0 or stop < start:
        raise InputFormatError(f"the markers {BEGIN!r} ... {END!r} are missing or out of order", where)
    return text[: start + len(BEGIN)] + "\n\n" + render_tables() + "\n" + text[stop:]


# =========================================================================== CLI
def _vectors_text(_: str | None) -> str:
    from .vectors import build_document, render_json

    return render_json(build_document())


def _doc_text(current: str | None) -> str:
    if current is None:
        raise InputFormatError("does not exist: the doc command only refreshes its tables", str(DOC))
    return replace_generated(current)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m protocol",
        description=__doc__.splitlines()[0],
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="what", required=True)
    for name, default, help_ in (
        ("vectors", VECTORS, "the canonical test vectors (JSON)"),
        ("doc", DOC, "the generated byte tables of docs/protocol.md"),
    ):
        p = sub.add_parser(
            name, help=help_, epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter
        )
        mode = p.add_mutually_exclusive_group(required=True)
        mode.add_argument("--write", action="store_true", help="write the file")
        mode.add_argument("--check", action="store_true", help="exit 1 if the file is not up to date")
        p.add_argument("path", nargs="?", type=Path, default=default, help=f"file (default {default})")
    args = parser.parse_args(argv)
    render = _vectors_text if args.what == "vectors" else _doc_text
    path: Path = args.path
    current = path.read_text(encoding="utf-8") if path.exists() else None
    try:
        wanted = render(current)
    except InputFormatError as exc:
        sys.stderr.write(f"error: {exc}\n")
        return 2
    if args.check:
        if current != wanted:
            sys.stderr.write(f"{path} is out of date: run python -m protocol {args.what} --write\n")
            return 1
        sys.stdout.write(f"{path} is up to date\n")
        return 0
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(wanted, encoding="utf-8")
    tmp.replace(path)
    sys.stdout.write(f"wrote {path}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
