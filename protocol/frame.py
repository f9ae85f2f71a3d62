"""Frames: header + payload + CRC-16, COBS-encoded, delimited by 0x00. Sans-IO.

Unencoded frame (all fields little-endian)::

    offset  size  field
    0       1     version      protocol version (PROTOCOL_VERSION)
    1       1     msg_id       message id (protocol.messages.CATALOGUE)
    2       1     seq          sequence number, per sender, +1 per new frame (mod 256)
    3       1     flags        bit 0 ACK_REQUESTED, bit 1 RETRANSMIT, others 0
    4       n     payload      0..250 bytes, the message's fields
    4+n     2     crc          CRC-16/CCITT-FALSE over bytes 0..4+n-1

On the wire: ``COBS(frame) + b"\\x00"``. At most 259 bytes including the delimiter.
A receiver that sees corruption discards up to the next 0x00 and resynchronises there, so a bad frame
costs that frame only.

Speed: a frame is encoded by its message's generated encoder (one ``struct`` call for header and payload,
:mod:`protocol.compiled`) and sealed (CRC + COBS + delimiter) by one call to :mod:`protocol.speedups` (C
when built); a chunk is unsealed by one call and decoded by the generated decoder. Anything those fast
paths do not take certainly valid goes through the reference path below (``cobs``, ``crc``, the layout
interpreter), which is also the one that words every error.
"""

from __future__ import annotations

import enum
import re
import struct
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field
from typing import Any

from . import cobs
from .compiled import MessageCodec, fast_constructor
from .crc import crc16_ccitt_false
from .errors import FieldRangeError, FrameError, ProtocolError
from .fields import PayloadLengthError, Scalar
from .messages import CODECS, LAYOUTS, PROTOCOL_VERSION, Flags, encode_payload
from .speedups import seal, unseal

HEADER = struct.Struct("<BBBB")
CRC = struct.Struct("<H")
HEADER_SIZE = HEADER.size
CRC_SIZE = CRC.size
MAX_PAYLOAD = 250
MIN_FRAME = HEADER_SIZE + CRC_SIZE
MAX_FRAME = HEADER_SIZE + MAX_PAYLOAD + CRC_SIZE
MAX_ENCODED = cobs.max_encoded_len(MAX_FRAME)
"""Longest COBS-encoded frame (without delimiter); a longer run without 0x00 is garbage."""
DELIMITER = b"\x00"
_CHUNK = re.compile(rb"[^\x00]+")
"""A chunk between delimiters (runs of delimiters are idle fill)."""


class BadFrameReason(enum.Enum):
    """Why a delimited chunk of bytes was not a valid frame."""

    COBS = "cobs"  # invalid COBS encoding
    TOO_SHORT = "too_short"  # fewer bytes than header + CRC
    TOO_LONG = "too_long"  # more than MAX_ENCODED bytes before a delimiter
    CRC = "crc"  # checksum mismatch
    VERSION = "version"  # unsupported protocol version
    UNKNOWN_ID = "unknown_id"  # message id not in the catalogue
    LENGTH = "length"  # payload shorter or longer than the message's fields
    FIELD_RANGE = "field_range"  # a field value outside its documented range


@dataclass(frozen=True, slots=True)
class Frame:
    """A decoded, valid frame."""

    message: Any
    seq: int
    flags: Flags
    version: int = PROTOCOL_VERSION

    @property
    def msg_id(self) -> int:
        return int(self.message.MSG_ID)


@dataclass(frozen=True, slots=True)
class BadFrame:
    """A chunk between delimiters that did not decode; ``size`` is its encoded length in bytes."""

    reason: BadFrameReason
    detail: str
    size: int


Event = Frame | BadFrame


_FLAGS = tuple(Flags(v) for v in range(256))
"""The header's flags byte as Flags, by value (every byte decodes: unknown bits are kept)."""
_new_frame = fast_constructor(Frame)


def _first_use(msg_id: int) -> tuple[Callable[[Any, int, int], bytes | None], Callable[[bytes], Any]]:
    """The encoder and decoder that stand for message ``msg_id``'s until its first frame: each generates
    the message's codec (:data:`~protocol.messages.CODECS`), puts it in their place, and calls it."""

    def take() -> MessageCodec:
        codec = CODECS[msg_id]
        _ENCODERS[msg_id], _DECODERS[msg_id] = codec.encode, codec.decode
        return codec

    def encode(message: Any, seq: int, flags: int) -> bytes | None:
        return take().encode(message, seq, flags)

    def decode(body: bytes) -> Any:
        return take().decode(body)

    return encode, decode


_ENCODERS: dict[int, Callable[[Any, int, int], bytes | None]] = {}
_DECODERS: dict[int, Callable[[bytes], Any]] = {}
for _msg_id in CODECS:
    _ENCODERS[_msg_id], _DECODERS[_msg_id] = _first_use(_msg_id)
del _msg_id
_MAX_BODY = HEADER_SIZE + MAX_PAYLOAD
_HEADER_BYTE = Scalar("B")
"""The header's ``seq`` and ``flags``: one byte each, held to the rule of every u8 field (an int, not a
bool, 0..255). A range check alone let 1.5 or 0.0 through to ``struct``, whose error was a traceback."""
_SEQ_BYTES = tuple(bytes((seq,)) for seq in range(256))
"""A sequence number as the one byte it is in the header, by value."""


def encode_frame(message: Any, seq: int, flags: int = 0) -> bytes:
    """The wire bytes (COBS + delimiter) of one frame. Raises FieldRangeError for bad fields."""
    return seal(encode_body(message, seq, flags))


def encode_body(message: Any, seq: int, flags: int = 0) -> bytes:
    """One frame before it is sealed: header and payload, no CRC, no COBS (what :func:`encode_frame`
    seals). Raises FieldRangeError for bad fields, ProtocolError for a payload over MAX_PAYLOAD."""
    if not _HEADER_BYTE.check(seq):
        raise FieldRangeError("header", "seq", seq)
    if not _HEADER_BYTE.check(flags):
        raise FieldRangeError("header", "flags", flags)
    body = _ENCODERS[message.MSG_ID](message, seq, flags)
    if body is None:  # not certainly valid: the reference encodes it or raises the exact error
        payload = encode_payload(message)
        body = HEADER.pack(PROTOCOL_VERSION, message.MSG_ID, seq, flags) + payload
    if len(body) > _MAX_BODY:
        size = len(body) - HEADER_SIZE
        raise ProtocolError(f"{type(message).__name__} payload is {size} bytes > {MAX_PAYLOAD}")
    return body


def _decode_fast(encoded: bytes) -> Frame | None:
    """The frame in a chunk of at most MAX_ENCODED bytes if it is certainly valid, else None."""
    body = unseal(encoded, MIN_FRAME, MAX_FRAME)
    if body is None or body[0] != PROTOCOL_VERSION:
        return None
    decode = _DECODERS.get(body[1])
    message = None if decode is None else decode(body)
    return None if message is None else _new_frame(message, body[2], _FLAGS[body[3]], PROTOCOL_VERSION)


def decode_frame(encoded: bytes) -> Frame:
    """Decode one COBS chunk (without its delimiter). Raises FrameError with a BadFrameReason."""
    if len(encoded) <= MAX_ENCODED:
        frame = _decode_fast(encoded)
        if frame is not None:
            return frame
    return _decode_reference(encoded)


def _decode_reference(encoded: bytes) -> Frame:
    """:func:`decode_frame` step by step in pure Python: what says why a chunk is not a frame."""
    if len(encoded) > MAX_ENCODED:
        raise FrameError(BadFrameReason.TOO_LONG, f"{len(encoded)} bytes > {MAX_ENCODED}")
    body = cobs.decode(encoded)
    if len(body) < MIN_FRAME:
        raise FrameError(BadFrameReason.TOO_SHORT, f"{len(body)} bytes < {MIN_FRAME}")
    if len(body) > MAX_FRAME:
        raise FrameError(BadFrameReason.TOO_LONG, f"{len(body)} bytes > {MAX_FRAME}")
    (crc,) = CRC.unpack_from(body, len(body) - CRC_SIZE)
    computed = crc16_ccitt_false(body[:-CRC_SIZE])
    if crc != computed:
        raise FrameError(BadFrameReason.CRC, f"received {crc:#06x}, computed {computed:#06x}")
    version, msg_id, seq, flags = HEADER.unpack_from(body)
    if version != PROTOCOL_VERSION:
        raise FrameError(BadFrameReason.VERSION, f"version {version}, this end speaks {PROTOCOL_VERSION}")
    layout = LAYOUTS.get(msg_id)
    if layout is None:
        raise FrameError(BadFrameReason.UNKNOWN_ID, f"message id {msg_id:#04x}")
    payload = body[HEADER_SIZE:-CRC_SIZE]
    try:
        message, end = layout.decode_from(payload, 0, layout.name)
    except PayloadLengthError as exc:
        raise FrameError(BadFrameReason.LENGTH, str(exc)) from None
    except FieldRangeError as exc:
        raise FrameError(BadFrameReason.FIELD_RANGE, str(exc)) from None
    if end != len(payload):
        raise FrameError(BadFrameReason.LENGTH, f"{layout.name}: {len(payload) - end} trailing byte(s)")
    return Frame(message, seq, Flags(flags), version)


@dataclass
class LinkCounters:
    """What a Deframer has seen. ``bad`` counts bad frames by reason."""

    bytes: int = 0
    frames: int = 0
    bad: dict[BadFrameReason, int] = field(default_factory=dict)
    resyncs: int = 0
    seq_gaps: int = 0
    duplicates: int = 0

    @property
    def bad_total(self) -> int:
        return sum(self.bad.values())


class Deframer:
    """Byte stream in, events out. Bounded memory: never holds more than one maximum frame.

    ``feed(data)`` returns the events completed by ``data`` in order. A run of more than ``MAX_ENCODED``
    bytes without a delimiter is discarded as one TOO_LONG bad frame (counted as a resync) and the
    deframer skips to the next delimiter. Empty chunks (consecutive delimiters) are idle fill and ignored.
    Sequence numbers: a jump of k > 1 adds k-1 to ``seq_gaps``; a repeat of the last number (a
    retransmission) adds to ``duplicates``. ``renumbered_by``: message ids that begin their sender's
    numbering afresh, the step to one counted as neither (a board passes ``Hello``'s: a restarted host
    numbers its frames from 0 again, and the jump from its predecessor's last number loses nothing).
    """

    def __init__(self, renumbered_by: Collection[int] = ()) -> None:
        self._buf = bytearray()
        self._skipping = False
        self._last_seq: int | None = None
        self._renumbered_by = frozenset(renumbered_by)
        self.counters = LinkCounters()

    def reset(self) -> None:
        """Forget a partial frame and the sequence history (e.g. after a reconnect); keep counters."""
        self._buf.clear()
        self._skipping = False
        self._last_seq = None

    def feed(self, data: bytes) -> list[Event]:
        """The events completed by ``data``. Memory stays within one maximum frame whatever is fed: the
        chunks between delimiters are found one at a time (runs of delimiters skipped in C), and an overlong
        one is measured, never copied."""
        counters = self.counters
        counters.bytes += len(data)
        events: list[Event] = []
        first = data.find(0)
        if first < 0:
            self._append_partial(data, 0, events)
            return events
        # The chunk a previous feed left open ends at the first delimiter.
        if self._skipping:
            self._skipping = False
        elif self._buf or first:
            size = len(self._buf) + first
            if size > MAX_ENCODED:
                self._too_long(events, size)
            elif self._buf:
                self._buf += data[:first]
                self._chunk(bytes(self._buf), events)
            else:  # nothing left open: the chunk is the data's own (not copied through the buffer)
                self._chunk(bytes(data[:first]), events)
            self._buf.clear()
        end = len(data)
        if first + 1 == end:  # one frame, its delimiter last: a board's read, every control tick
            return events
        for match in _CHUNK.finditer(data, first + 1):
            start, stop = match.span()
            if stop == end:  # no delimiter after it: the start of a frame still arriving
                self._append_partial(data, start, events)
                break
            if stop - start > MAX_ENCODED:
                self._too_long(events, stop - start)
                continue
            chunk = data[start:stop]
            frame = _decode_fast(chunk)
            if frame is None:  # not certainly valid: the reference decodes it or says why not
                self._chunk(chunk, events, _decode_reference)
                continue
            seq = frame.seq  # _count_seq and the frame count, inline on the hot path
            last = self._last_seq
            self._last_seq = seq
            if last is not None and (seq - last) & 0xFF != 1 and frame.msg_id not in self._renumbered_by:
                self._count_step((seq - last) & 0xFF)
            counters.frames += 1
            events.append(frame)
        return events

    def _chunk(
        self, chunk: bytes, events: list[Event], decode: Callable[[bytes], Frame] = decode_frame
    ) -> None:
        """One complete chunk of at most MAX_ENCODED bytes: a frame or a bad frame."""
        try:
            frame = decode(chunk)
        except FrameError as exc:
            self._bad(events, exc.reason, exc.detail, len(chunk))  # type: ignore[arg-type]
            return
        self._count_seq(frame)
        self.counters.frames += 1
        events.append(frame)

    def _too_long(self, events: list[Event], size: int) -> None:
        self._bad(events, BadFrameReason.TOO_LONG, f"{size} bytes without a delimiter", size)
        self.counters.resyncs += 1

    def _append_partial(self, data: bytes, start: int, events: list[Event]) -> None:
        """Keep ``data[start:]``, the start of a frame still arriving; past MAX_ENCODED, report it and skip
        to the next delimiter (without copying what is skipped)."""
        if self._skipping:
            return
        size = len(self._buf) + len(data) - start
        if size > MAX_ENCODED:
            self._bad(
                events, BadFrameReason.TOO_LONG, f"more than {MAX_ENCODED} bytes without a delimiter", size
            )
            self.counters.resyncs += 1
            self._buf.clear()
            self._skipping = True
            return
        self._buf += data[start:] if start else data

    def _bad(self, events: list[Event], reason: BadFrameReason, detail: str, size: int) -> None:
        self.counters.bad[reason] = self.counters.bad.get(reason, 0) + 1
        events.append(BadFrame(reason, detail, size))

    def _count_seq(self, frame: Frame) -> None:
        last = self._last_seq
        self._last_seq = frame.seq
        if last is not None and frame.msg_id not in self._renumbered_by:
            self._count_step((frame.seq - last) & 0xFF)

    def _count_step(self, step: int) -> None:
        """Sequence step from one frame to the next (mod 256): 0 a duplicate, k > 1 a gap of k - 1."""
        if step == 0:
            self.counters.duplicates += 1
        elif step > 1:
            self.counters.seq_gaps += step - 1


class Framer:
    """Sender side: numbers frames. ``encode(msg)`` takes the next sequence number; a retry passes the
    original ``seq`` and gets the RETRANSMIT flag. A message checked when it is given but sent later, or
    never (a setpoint that waits for its slot and may be replaced by a newer one), is encoded once by
    :meth:`prepare` and numbered when it leaves by :meth:`send_prepared`."""

    def __init__(self, first_seq: int = 0) -> None:
        self._next = first_seq & 0xFF

    @property
    def next_seq(self) -> int:
        return self._next

    def encode(self, message: Any, flags: int = 0, seq: int | None = None) -> tuple[int, bytes]:
        """Returns ``(seq, wire_bytes)``. A message that fails to encode (``FieldRangeError``) uses up no
        sequence number, so the receiver sees no gap for a frame that was never sent."""
        new = seq is None
        if seq is None:
            seq = self._next
        else:
            flags |= Flags.RETRANSMIT
        if getattr(message, "RELIABLE", False):
            flags |= Flags.ACK_REQUESTED
        wire = encode_frame(message, seq, flags)
        if new:
            self._next = (seq + 1) & 0xFF
        return seq, wire

    def prepare(self, message: Any) -> bytes:
        """``message`` encoded now (FieldRangeError, ProtocolError here), its sequence number left to
        :meth:`send_prepared`: the unsealed frame (:func:`encode_body`) with sequence number 0. Uses up
        no sequence number."""
        flags = Flags.ACK_REQUESTED if getattr(message, "RELIABLE", False) else 0
        return encode_body(message, 0, flags)

    def send_prepared(self, body: bytes) -> tuple[int, bytes]:
        """``(seq, wire_bytes)`` of a body from :meth:`prepare`, with the next sequence number: the same
        bytes :meth:`encode` gives for its message."""
        seq = self._next
        wire = seal(body[:2] + _SEQ_BYTES[seq] + body[3:])  # the header's third byte is seq
        self._next = (seq + 1) & 0xFF
        return seq, wire


def decode_stream(data: bytes | Iterable[bytes]) -> list[Event]:
    """Convenience: run a fresh Deframer over ``data`` (bytes or an iterable of chunks)."""
    deframer = Deframer()
    if isinstance(data, (bytes, bytearray)):
        return deframer.feed(bytes(data))
    events: list[Event] = []
    for chunk in data:
        events.extend(deframer.feed(chunk))
    return events
