"""COBS and CRC-16 for the frame codec's hot path: the C extension when there is one, else the reference.

``protocol._speedups`` (``protocol/_speedups.c``, built at install by ``setup.py`` as an optional
extension) computes exactly what the pure-Python :mod:`protocol.cobs` and :mod:`protocol.crc` compute;
those stay the reference, and the codec runs on them when the extension was not built (no C compiler at
install) or when ``PROTOCOL_PURE=1`` is set in the environment before ``protocol`` is imported (to debug,
or to compare). :data:`NATIVE` says which is in force.

Two frame-level operations fuse the per-frame work into one call each:

* :func:`seal` — ``COBS(body + CRC-16 little-endian) + b"\\x00"``: a frame as it goes on the wire;
* :func:`unseal` — a chunk between delimiters back to the frame without its CRC, or ``None`` if its COBS
  is invalid, its length is outside ``[min_len, max_len]`` or its CRC is wrong. ``None`` says only *that*
  the chunk is bad: the caller runs the reference checks to say *why* (the error text is built only on
  failure, in one place).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from types import ModuleType

from . import cobs
from .crc import crc16_ccitt_false
from .errors import FrameError

PURE_ENV = "PROTOCOL_PURE"
"""Environment variable: set to anything but ``""`` or ``"0"`` to run on the pure-Python reference."""


def seal_reference(body: bytes) -> bytes:
    """The wire bytes of a frame ``body`` (header + payload): COBS of body + CRC, then the delimiter."""
    return cobs.encode(body + crc16_ccitt_false(body).to_bytes(2, "little")) + b"\x00"


def unseal_reference(chunk: bytes, min_len: int, max_len: int) -> bytes | None:
    """The frame in ``chunk`` (no delimiter) without its CRC, or None if its COBS, length or CRC is bad."""
    try:
        frame = cobs.decode(chunk)
    except FrameError:
        return None
    if not min_len <= len(frame) <= max_len:
        return None
    body = frame[:-2]
    if int.from_bytes(frame[-2:], "little") != crc16_ccitt_false(body):
        return None
    return body


def cobs_decode_reference(data: bytes) -> bytes | None:
    """:func:`protocol.cobs.decode`, with None for invalid input (the C function's contract)."""
    try:
        return cobs.decode(data)
    except FrameError:
        return None


def _load_native() -> ModuleType | None:
    if os.environ.get(PURE_ENV, "") not in ("", "0"):
        return None
    try:
        from . import _speedups  # type: ignore[attr-defined]
    except ImportError:  # not built: no C compiler at install
        return None
    return _speedups


_native = _load_native()
NATIVE: bool = _native is not None
"""True when the C extension is in use, False when the pure-Python reference is."""

cobs_encode: Callable[[bytes], bytes] = _native.cobs_encode if _native else cobs.encode
cobs_decode: Callable[[bytes], bytes | None] = _native.cobs_decode if _native else cobs_decode_reference
crc16: Callable[..., int] = _native.crc16 if _native else crc16_ccitt_false
seal: Callable[[bytes], bytes] = _native.seal if _native else seal_reference
unseal: Callable[[bytes, int, int], bytes | None] = _native.unseal if _native else unseal_reference

__all__ = [
    "NATIVE",
    "PURE_ENV",
    "cobs_decode",
    "cobs_decode_reference",
    "cobs_encode",
    "crc16",
    "seal",
    "seal_reference",
    "unseal",
    "unseal_reference",
]
