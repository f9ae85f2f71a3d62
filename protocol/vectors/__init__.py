"""Canonical test vectors of the wire protocol, and the check of a codec against them.

``fixtures/protocol_vectors.json`` is generated from this package (``python -m protocol vectors --write``)
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

Modules: the data — :mod:`.frames`, :mod:`.bad_frames`, :mod:`.streams` (the case tables); the
generator — :mod:`.build` (the document and its JSON text), with :mod:`.values` (field values <-> JSON)
and :mod:`.catalogue` (payload sizes, summary rows, flag names); the checker — :mod:`.check`.

Everything here is pure (no file I/O) except :func:`check_vectors`, the thin entry point that reads the
file for ``hil selftest``; :func:`check_document` does the checking on an already-parsed document.
"""

from __future__ import annotations

from .bad_frames import build_wire
from .build import FORMAT, FORMAT_VERSION, build_document, render_json
from .catalogue import payload_size_range
from .check import VectorResult, check_document, check_vectors
from .values import from_json, to_json

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
