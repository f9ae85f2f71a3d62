"""Consistent Overhead Byte Stuffing (Cheshire & Baker, 1999).

The encoded form contains no 0x00 byte, so 0x00 can delimit frames and a receiver resynchronises at the
next delimiter after any corruption. Overhead is one byte per started 254 bytes of input.
Canonical form (what :func:`encode` produces and the test vectors use): a block of 254 non-zero bytes
is written as 0xFF + 254 bytes; the input's end is always closed by a group, so an input ending in a
254-byte run ends with an extra ``0x01`` code. :func:`decode` accepts either form.
"""

from __future__ import annotations

from .errors import FrameError

_FULL = 254


def max_encoded_len(n: int) -> int:
    """Upper bound on ``len(encode(x))`` for ``len(x) == n`` (without the delimiter)."""
    return n + n // _FULL + 1


def encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (no trailing delimiter)."""
    out = bytearray()
    for block in bytes(data).split(b"\x00"):
        while len(block) >= _FULL:
            out.append(0xFF)
            out += block[:_FULL]
            block = block[_FULL:]
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def decode(data: bytes) -> bytes:
    """Decode one COBS group sequence (no delimiter inside). Raises :class:`FrameError` (reason COBS)."""
    zero = data.find(b"\x00")
    if zero >= 0:
        raise _error(f"zero byte inside frame at offset {zero}")
    if 0xFF in data:
        return _decode_with_full_blocks(data)
    # No 0xFF byte, so no full block: every code byte but the first stands for a zero. Walk the codes
    # and zero them in a copy, then drop the first: one cheap step per group.
    n = len(data)
    out = bytearray(data)
    i = 0
    while i < n:
        end = i + data[i]
        if end > n:
            raise _error(f"group at offset {i} runs {end - n} byte(s) past the end")
        if end < n:
            out[end] = 0
        i = end
    return bytes(out[1:])


def _decode_with_full_blocks(data: bytes) -> bytes:
    """The general decoder (0xFF codes: a 254-byte block not followed by a zero)."""
    out = bytearray()
    i = 0
    n = len(data)
    while i < n:
        code = data[i]
        end = i + code
        if end > n:
            raise _error(f"group at offset {i} runs {end - n} byte(s) past the end")
        out += data[i + 1 : end]
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


def _error(detail: str) -> FrameError:
    from .frame import BadFrameReason  # local: frame imports this module

    return FrameError(BadFrameReason.COBS, detail)
