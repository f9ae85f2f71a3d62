"""The checker: this codec against a vectors document, in both directions (encode the fields -> the wire
bytes exactly; decode the wire bytes -> the fields), plus bad frames, streams, COBS, CRC and coverage."""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .. import cobs
from ..crc import crc16_ccitt_false
from ..errors import FieldRangeError, ProtocolError
from ..frame import BadFrame, BadFrameReason, Deframer, Frame, encode_frame
from ..messages import BY_ID, CATALOGUE, PROTOCOL_VERSION, SCHEMA_HASH
from .build import FORMAT, FORMAT_VERSION
from .catalogue import describe_catalogue, flag_names
from .values import from_json, to_json

MAX_VECTORS_BYTES = 16 << 20
"""The largest vectors file read (16 MiB; the canonical one is ~55 kB)."""


@dataclass(frozen=True, slots=True)
class VectorResult:
    """One check: ``name`` names the vector (or section), ``detail`` says what differed."""

    name: str
    ok: bool
    detail: str = ""


def check_vectors(path: str | Path) -> list[VectorResult]:
    """Check this codec against the vectors file at ``path`` (the one file read in ``protocol``).

    An unreadable or malformed file is one failed result, not an exception: one that is no regular file
    (``/dev/zero`` never ends, a FIFO's open waits for a writer), larger than :data:`MAX_VECTORS_BYTES`,
    or whose JSON nests too deep or holds an integer of thousands of digits too. (``hil selftest`` reads
    the file as hil reads every document, and calls :func:`check_document`.)"""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise OSError(f"{path}: not a regular file")
        with open(path, "rb") as f:
            data = f.read(MAX_VECTORS_BYTES + 1)
        if len(data) > MAX_VECTORS_BYTES:
            raise OSError(f"{path}: larger than {MAX_VECTORS_BYTES} bytes")
        document = json.loads(data.decode("utf-8-sig"))  # a BOM, as hil reads every document
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:  # JSONDecodeError: a ValueError
        return [VectorResult(str(path), False, f"cannot read vectors: {exc}")]
    return check_document(document)


def check_document(document: Any) -> list[VectorResult]:
    """Every check of :func:`check_vectors` on an already-parsed document (pure)."""
    if not isinstance(document, Mapping) or document.get("format") != FORMAT:
        return [VectorResult("format", False, f"not a {FORMAT!r} document")]
    results = [_check_header(document)]
    sections: dict[str, list[Any]] = {}
    for key in SECTIONS:
        sections[key], problem = _section(document, key)
        if problem is not None:
            results.append(problem)
    frames = sections["frames"]
    for i, vector in enumerate(frames):
        results.append(_guarded(f"frames[{i}]", vector, _check_frame))
    for i, vector in enumerate(sections["bad_frames"]):
        results.append(_guarded(f"bad_frames[{i}]", vector, _check_bad))
    named = {_text(v, "name"): v for v in frames if _text(v, "name") is not None}
    for i, vector in enumerate(sections["streams"]):
        results.append(_guarded(f"streams[{i}]", vector, lambda v: _check_stream(v, named)))
    for i, vector in enumerate(sections["cobs"]):
        results.append(_guarded(f"cobs[{i}]", vector, _check_cobs))
    for i, vector in enumerate(sections["crc"]):
        results.append(_guarded(f"crc[{i}]", vector, _check_crc))
    results.append(_check_messages(document.get("messages", [])))
    results.extend(_check_coverage(sections))
    return results


SECTIONS = ("frames", "bad_frames", "streams", "cobs", "crc")
"""The document's arrays of vectors, each checked vector by vector."""


def _section(document: Mapping[str, Any], key: str) -> tuple[list[Any], VectorResult | None]:
    """The array ``key`` of ``document`` (absent: none), or none and a failed result naming it: a section
    that is a number or null (a hand's edit) ended the selftest in a TypeError traceback."""
    section = document.get(key, [])
    if isinstance(section, list):
        return section, None
    return [], VectorResult(key, False, f"expected an array of vectors, got {type(section).__name__}")


def _text(vector: Any, key: str) -> str | None:
    """A vector's ``key`` when it is a string (a name, a message, a reason), else None: a list there
    (unhashable) ended the selftest in a TypeError traceback."""
    value = vector.get(key) if isinstance(vector, Mapping) else None
    return value if isinstance(value, str) else None


def _guarded(where: str, vector: Any, check: Callable[[Mapping[str, Any]], list[str]]) -> VectorResult:
    """``check`` of one vector, whatever it raises a failed result naming the vector: the document is
    another program's (or a hand's), and a value of a type the codec never meets (a float ``seq`` reached
    ``struct``: a ``struct.error`` traceback) must be a report line, never the end of the selftest."""
    name = vector.get("name", where) if isinstance(vector, Mapping) else where
    try:
        if not isinstance(vector, Mapping):
            raise ProtocolError("expected an object")
        if not isinstance(name, str):  # a list there passed, its stream vectors unable to name it
            raise ProtocolError(f"name: expected a string, got {type(name).__name__}")
        problems = check(vector)
    except Exception as exc:  # noqa: BLE001 — any failure on a malformed vector is that vector's report
        problems = [f"malformed vector: {type(exc).__name__}: {str(exc)[:200]}"]
    return VectorResult((name if isinstance(name, str) else where)[:200], not problems, "; ".join(problems))


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
    except FieldRangeError as exc:
        problems.append(f"encode raised {exc}")
        if exc.message_name == "header":  # seq or flags no header byte: nothing below can compare with it
            return problems
    except ProtocolError as exc:
        problems.append(f"encode raised {exc}")
    else:
        if encoded != wire:
            problems.append(f"encode gave {encoded.hex()}, vector has {wire.hex()}")
    if flag_names(v["flags"]) != v["flag_names"]:
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
    if rows != describe_catalogue():
        return VectorResult("messages", False, "the file's catalogue summary differs from this codec's")
    return VectorResult("messages", True)


def _check_coverage(sections: Mapping[str, list[Any]]) -> list[VectorResult]:
    """Every message has a canonical frame and every bad-frame reason a broken one."""
    covered = {_text(v, "message") for v in sections["frames"]}
    missing = sorted(cls.__name__ for cls in CATALOGUE if cls.__name__ not in covered)
    reasons = {_text(v, "reason") for v in sections["bad_frames"]}
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
