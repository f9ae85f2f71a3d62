"""The protocol's frames on a CAN bus (classic CAN and CAN FD), sans-IO.

What travels is exactly the serial wire form of a frame — ``COBS(header + payload + CRC) + 0x00`` as
:class:`protocol.frame.Framer` produces it — cut into segments. Concatenating a frame's segment
payloads gives back the serial bytes, so the receiver hands them to the ordinary
:class:`protocol.frame.Deframer` (same events, same counters, same CRC check end to end) and a
serial ↔ CAN gateway is a byte copy. The COBS delimiter marks the last segment, which also makes
CAN FD's padding (a frame's data is 0..8, 12, 16, 20, 24, 32, 48 or 64 bytes) unambiguous.

Arbitration id (11-bit base format, the same on classic CAN and CAN FD)::

    bit  10 9 8 | 7         | 6 5 4 3 2 1 0
         priority | direction | node id (0..127)

* ``priority`` (0 = wins arbitration) from the message id: 0 COMMAND (Arm, Disarm, SetMode, EscCalibrate,
  Ack, Nack), 1 CONTROL (ActuatorSetpoint, RawPulses), 2 LINK (Hello, HelloReply, Heartbeat), 3 STATUS
  (Telemetry, EscCalibrationStatus), 4 BULK (CalibrationData, CalibrationRequest), 5 LOG (Log), 6 any
  other id; 7 unused.
* ``direction``: 0 host → board, 1 board → host, so host and board never send the same id.
* ``node id``: the board's address; one host talks to up to 128 boards on one bus.

Segment (the CAN frame's data)::

    byte 0      bits 7..6 transfer id (per arbitration id, +1 mod 4 per frame)
                bits 5..0 segment index (0, 1, 2, ...)
    bytes 1..   the next 7 (classic) or 63 (FD) bytes of the wire frame; every segment but the last is
                full, the last one ends at the 0x00 delimiter (FD: then 0x00 padding to a valid length)

A frame takes at most 37 classic or 5 FD segments. Receivers reassemble per arbitration id, place
segments by index (so reordering within a frame is harmless), and emit the frame once every index up
to the delimiter's has arrived. A sender sends one frame after another on an arbitration id, so a segment
under another transfer id ends the frames being assembled under the others. A frame that cannot complete
— a segment lost, a conflicting duplicate, the sender moved on — is discarded and counted
(``incomplete``), never delivered half-built; one that assembles but fails its CRC (segments of two frames
joined after the 2-bit transfer id wrapped) is counted (``spliced``), and assembly restarts from the
newest segment. Frames cut by the receiver's own start or reset are counted apart (``cut``): those in
flight at a reset, and on each arbitration id the tail heard before any first segment — a receiver that
joins a bus its peer already streams on mostly starts mid-frame (it cannot tell that from the very first
head lost, which is then counted there too). A repeat of
the segment that completed a frame, arriving next on its arbitration id (CAN's "double reception": the
transmitter saw an error frame and sends the same CAN frame again at once), is counted as a duplicate;
a repeat within a frame still being assembled is too. Given the frames' receive times (``at``; python-can's
``Message.timestamp``), a "repeat" heard more than :data:`REPEAT_WINDOW_S` after the frame it equals is
not one: a sender restarted meanwhile (its transfer ids and sequence numbers from 0 again) says the same
first frame again — a host killed during its handshake and started again sends the very same ``Hello`` —
and that frame is new. Memory is bounded: per arbitration id ``window``
partial frames and one segment, for at most ``max_streams`` arbitration ids.

What cannot be a segment is counted before it can touch a frame in flight: frames of the other kind
than the receiver's (``wrong_kind``; a receiver taking both never joins the two kinds in one frame),
error and remote frames (``error_frames``), and ``malformed`` data — under 2 bytes, over the kind's
limit, a CAN FD length no DLC gives, an index past the last segment, a short middle segment, a first
segment ending a frame shorter than :data:`MIN_WIRE`. One segment that fails its CRC is ``malformed``
too (it joins nothing: not a splice). A python-can message whose fields are not a CAN frame's (an id that
is no integer, data that is not bytes, a dlc other than the data's length, a flag that is not a bool) is
``invalid`` (:meth:`CanReassembler.admit`): python-can builds such messages from stray udp_multicast
datagrams, and a receiver never raises on one.
"""

from __future__ import annotations

import enum
import math
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import NamedTuple, TypeGuard

from .errors import ConfigError, ProtocolError, value_repr
from .frame import DELIMITER, MAX_ENCODED, MIN_FRAME
from .messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    CalibrationData,
    CalibrationRequest,
    Disarm,
    EscCalibrate,
    EscCalibrationStatus,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    Nack,
    RawPulses,
    SetMode,
    Telemetry,
)
from .speedups import unseal

MAX_WIRE = MAX_ENCODED + 1
"""Longest wire frame including its delimiter."""
MIN_WIRE = MIN_FRAME + 2
"""Shortest wire frame: the smallest frame, its COBS code byte and its delimiter."""
CLASSIC_DATA = 8
FD_DATA = 64
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
"""The data lengths a CAN FD frame can have (DLC 0..15)."""
NODE_MAX = 0x7F
REPEAT_WINDOW_S = 0.1
"""Longest time (s) between a frame and a repeat of it: a CAN controller retransmits a frame at once (in
microseconds) after an error frame; no sender restarts (a process, an MCU's boot) this fast. A frame equal
to the last one heard on its arbitration id but later than this is a restarted sender's, and delivered."""
_TID_SHIFT = 6
_INDEX_MASK = 0x3F


class Priority(enum.IntEnum):
    """The arbitration id's top three bits: lower wins the bus."""

    COMMAND = 0
    CONTROL = 1
    LINK = 2
    STATUS = 3
    BULK = 4
    LOG = 5
    OTHER = 6


class Direction(enum.IntEnum):
    TO_BOARD = 0
    TO_HOST = 1


PRIORITY: dict[int, Priority] = {
    **{cls.MSG_ID: Priority.COMMAND for cls in (Arm, Disarm, SetMode, Ack, Nack, EscCalibrate)},
    **{cls.MSG_ID: Priority.CONTROL for cls in (ActuatorSetpoint, RawPulses)},
    **{cls.MSG_ID: Priority.LINK for cls in (Hello, HelloReply, Heartbeat)},
    **{cls.MSG_ID: Priority.STATUS for cls in (Telemetry, EscCalibrationStatus)},
    **{cls.MSG_ID: Priority.BULK for cls in (CalibrationData, CalibrationRequest)},
    Log.MSG_ID: Priority.LOG,
}
"""Priority class of each message id; ids not listed travel as ``Priority.OTHER``."""


@dataclass(frozen=True, slots=True)
class CanId:
    """The fields of an arbitration id."""

    priority: Priority
    direction: Direction
    node: int

    def __post_init__(self) -> None:
        if not 0 <= self.node <= NODE_MAX:
            raise ProtocolError(f"CAN node id {self.node} is outside 0..{NODE_MAX}")

    @property
    def value(self) -> int:
        """The 11-bit arbitration id."""
        return (int(self.priority) << 8) | (int(self.direction) << 7) | self.node

    @classmethod
    def parse(cls, arbitration_id: int) -> CanId:
        """Split an 11-bit id; raises :class:`ProtocolError` for an id outside this scheme — also for one
        that is not an integer at all (python-can builds a ``Message`` with a float id from a stray
        udp_multicast datagram, and its own check lets 901.5 through)."""
        if not _is_int(arbitration_id):
            raise ProtocolError(f"arbitration id {value_repr(arbitration_id)} is not an integer")
        if not 0 <= arbitration_id <= 0x7FF or arbitration_id >> 8 > Priority.OTHER:
            raise ProtocolError(f"arbitration id {arbitration_id:#x} is not in the vscmg-hil scheme")
        return cls(
            Priority(arbitration_id >> 8), Direction((arbitration_id >> 7) & 1), arbitration_id & NODE_MAX
        )


@dataclass(frozen=True, slots=True)
class CanFrame:
    """One CAN frame to send: ``can.Message(arbitration_id=f.arbitration_id, data=f.data,
    is_fd=f.is_fd, is_extended_id=False)`` in python-can."""

    arbitration_id: int
    data: bytes
    is_fd: bool = False


def _is_int(value: object) -> TypeGuard[int]:
    """An integer and not a bool (``True`` is an ``int`` to Python, never an identifier or a length)."""
    return isinstance(value, int) and not isinstance(value, bool)


def _flag(value: object) -> bool | None:
    """A python-can flag as a bool, or None when it is none: a stray datagram's ``"yes"``, ``2`` or
    ``None`` (0 and 1 pass: an interface may hand over a bit as an int)."""
    if isinstance(value, bool):
        return value
    if _is_int(value) and value in (0, 1):
        return bool(value)
    return None


def _receive_time(value: object) -> float | None:
    """A message's receive time in seconds, or None when it is not one (unset — python-can's 0.0 —, not
    a number, not finite, or an integer too large for a float)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not value:
        return None
    try:
        at = float(value)
    except OverflowError:
        return None
    return at if math.isfinite(at) else None


class Received(NamedTuple):
    """The fields of a received CAN data frame, checked (:meth:`CanReassembler.admit`): the arguments of
    :meth:`CanReassembler.feed`."""

    arbitration_id: int
    data: bytes
    is_fd: bool
    is_extended_id: bool
    at: float | None


def segment_payload(fd: bool) -> int:
    """Bytes of wire frame per segment (the data minus the 1-byte segment header)."""
    return (FD_DATA if fd else CLASSIC_DATA) - 1


def max_segments(fd: bool) -> int:
    """Most segments a frame can take."""
    per = segment_payload(fd)
    return -(-MAX_WIRE // per)


def _fd_length(n: int) -> int:
    return next(length for length in FD_LENGTHS if length >= n)


def _check_config(node: int, window: int | None = None, max_streams: int | None = None) -> None:
    if isinstance(node, bool) or not isinstance(node, int) or not 0 <= node <= NODE_MAX:
        raise ConfigError(f"{value_repr(node)} is outside 0..{NODE_MAX}", "CAN node id")
    for name, value in (("window", window), ("max_streams", max_streams)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise ConfigError(f"{value_repr(value)} must be an integer >= 1", f"CanReassembler.{name}")


# =========================================================================== sending
class CanSegmenter:
    """Sender side: wire frames in, CAN frames out. One per sending node (it keeps the transfer ids).

    ``direction`` is this sender's: a host uses ``Direction.TO_BOARD`` with the board's ``node`` id.
    """

    def __init__(self, node: int, direction: Direction, fd: bool = False) -> None:
        _check_config(node)
        self.node = node
        self.direction = Direction(direction)
        self.fd = fd
        self._tid: dict[int, int] = {}

    def arbitration_id(self, msg_id: int) -> int:
        return CanId(PRIORITY.get(msg_id, Priority.OTHER), self.direction, self.node).value

    def segment(self, wire: bytes) -> list[CanFrame]:
        """The CAN frames carrying one wire frame (``COBS(...) + 0x00``, as ``Framer.encode`` returns).

        Raises :class:`ProtocolError` for bytes that are not exactly one wire frame."""
        wire = bytes(wire)
        if len(wire) < 2 or wire[-1] != 0 or 0 in wire[:-1] or len(wire) > MAX_WIRE:
            raise ProtocolError(
                f"not one wire frame ({len(wire)} bytes; it must end with its only 0x00 and be at most "
                f"{MAX_WIRE} bytes)"
            )
        # Version and message id are never 0, so COBS leaves them in place: wire[0] is the first code
        # byte (>= 3) and wire[2] the message id.
        msg_id = wire[2] if wire[0] >= 3 else -1
        arb = self.arbitration_id(msg_id)
        tid = self._tid.get(arb, 0)
        self._tid[arb] = (tid + 1) & 0x3
        per = segment_payload(self.fd)
        frames = []
        for index, start in enumerate(range(0, len(wire), per)):
            data = bytes([(tid << _TID_SHIFT) | index]) + wire[start : start + per]
            if self.fd and len(data) not in FD_LENGTHS:
                data += bytes(_fd_length(len(data)) - len(data))
            frames.append(CanFrame(arb, data, self.fd))
        return frames


# =========================================================================== receiving
@dataclass
class CanStats:
    """What a :class:`CanReassembler` has seen."""

    segments: int = 0  # CAN frames accepted as segments
    frames: int = 0  # wire frames completed and delivered
    incomplete: int = 0  # partial frames discarded (a segment lost, conflicting, or the sender moved on)
    cut: int = 0  # partial frames cut by the receiver's start (a tail heard first) or reset: not a loss
    spliced: int = 0  # "complete" frames of 2+ segments that failed their CRC: different frames joined
    malformed: int = 0  # CAN frames that cannot be a segment (too short or long, bad index or FD length,
    # short middle, a frame shorter than the shortest wire frame) and one-segment frames failing their CRC
    duplicates: int = 0  # segments received twice with the same content
    ignored: int = 0  # CAN frames outside the scheme, for another node or the other direction
    wrong_kind: int = 0  # CAN FD frames on a classic link, classic frames on an FD link
    error_frames: int = 0  # CAN error frames and remote frames (never a segment; ``feed_message``)
    invalid: int = 0  # messages whose fields are not a CAN frame's: an id that is no integer or out of CAN's
    # range, data that is not bytes, a dlc other than the data's length, a flag that is not a bool


@dataclass
class _Partial:
    segments: dict[int, bytes] = field(default_factory=dict)
    last: int | None = None  # index of the segment holding the delimiter
    fd: bool = False  # the kind of CAN frame its segments came in (their size depends on it)


@dataclass
class _Stream:
    """One arbitration id: frames being assembled; the segment that completed the last delivered frame
    (transfer id, index, bytes) while it is the last segment heard (a double reception follows its
    original at once: that repeat is dropped at once); and the last frame delivered (transfer id, wire
    bytes), so that a repeat arriving later, before the sender's next frame, whose segments assemble into
    that frame byte for byte under its transfer id, is recognised as a duplicate too. Only the *last*
    frame: a frame four transfer ids on that equals an older one byte for byte is the sender's — a command
    retransmitted with its sequence number, or a stream of identical frames — and is delivered. Single
    segments are never judged against delivered frames: a later frame four transfer ids on (the frames
    between lost whole) may share a segment with one — a last segment holding only the delimiter, say."""

    partials: OrderedDict[int, _Partial] = field(default_factory=OrderedDict)
    headed: bool = False  # a first segment (index 0) has been heard: tails before it are the start's cut
    completed_by: tuple[int, int, bytes] | None = None
    delivered: tuple[int, bytes] | None = None  # (transfer id, wire frame) of the last frame delivered
    completed_at: float | None = None  # receive time of the segment that completed it (None: not given)


def _intact(wire: bytes) -> bool:
    """``wire`` (COBS + 0x00) decodes and its CRC holds: one whole frame, not pieces of two."""
    return unseal(wire[:-1], MIN_FRAME, len(wire)) is not None  # decoded is never longer than encoded


class CanReassembler:
    """Receiver side: CAN frames in, complete wire frames out (feed them to a ``Deframer``).

    ``node``/``direction`` filter what this end accepts (a host: ``direction=Direction.TO_HOST`` and
    its board's node; None accepts any); ``fd`` the kind of CAN frame (True: CAN FD, False: classic,
    None: either — segments of one frame are then still never taken from both kinds). Each arbitration
    id is one stream with up to ``window`` partial frames in flight; at most ``max_streams`` streams are
    tracked (the least recently heard is dropped).
    """

    def __init__(
        self,
        node: int | None = None,
        direction: Direction | None = None,
        window: int = 2,
        max_streams: int = 32,
        fd: bool | None = None,
    ) -> None:
        _check_config(0 if node is None else node, window, max_streams)
        self.node = node
        self.direction = None if direction is None else Direction(direction)
        self.fd = None if fd is None else bool(fd)
        self.window = window
        self.max_streams = max_streams
        self.stats = CanStats()
        self._streams: OrderedDict[int, _Stream] = OrderedDict()

    def reset(self) -> None:
        """Drop every partial frame, e.g. as a connection closes. They are counted as ``cut``, not as
        ``incomplete``: a peer that streams (a board's telemetry) is often mid-frame when its receiver
        closes, which says nothing about the link."""
        for stream in self._streams.values():
            self.stats.cut += len(stream.partials)
        self._streams.clear()

    def feed(
        self,
        arbitration_id: int,
        data: bytes,
        is_fd: bool = False,
        is_extended_id: bool = False,
        at: float | None = None,
    ) -> bytes:
        """One received CAN data frame; returns the wire frames it completed (possibly b"").

        ``at``: when it was received (s, any clock; None: unknown), so that a restarted sender's first
        frame is not taken for a repeat of its predecessor's last (:data:`REPEAT_WINDOW_S`)."""
        if not isinstance(data, (bytes, bytearray)) or _flag(is_fd) is None or _flag(is_extended_id) is None:
            self.stats.invalid += 1  # bytes(5) would be five zero bytes: never guess at what was meant
            return b""
        is_fd = bool(is_fd)
        if is_extended_id or not self._accepts(arbitration_id):
            self.stats.ignored += 1
            return b""
        if self.fd is not None and is_fd != self.fd:
            self.stats.wrong_kind += 1  # another node's traffic: never a segment of this link's frames
            return b""
        data = bytes(data)
        limit = FD_DATA if is_fd else CLASSIC_DATA
        per = segment_payload(is_fd)
        if len(data) < 2 or len(data) > limit or (is_fd and len(data) not in FD_LENGTHS):
            self.stats.malformed += 1
            return b""
        tid, index = data[0] >> _TID_SHIFT, data[0] & _INDEX_MASK
        chunk = data[1:]
        end = chunk.find(DELIMITER)
        if end >= 0:
            chunk = chunk[: end + 1]  # the rest is CAN FD padding
        if (
            index >= max_segments(is_fd)
            or (end < 0 and len(chunk) != per)
            or (index == 0 and end >= 0 and len(chunk) < MIN_WIRE)  # a frame shorter than any frame
        ):
            self.stats.malformed += 1
            return b""
        self.stats.segments += 1
        stream = self._stream(arbitration_id)
        if at is not None and stream.completed_at is not None and at - stream.completed_at > REPEAT_WINDOW_S:
            # Too late to repeat the last frame: whatever equals it now is a restarted sender's own.
            stream.completed_by = stream.delivered = stream.completed_at = None
        if stream.completed_by == (tid, index, chunk):
            self.stats.duplicates += 1  # the completing segment again, at once: CAN double reception
            return b""
        stream.completed_by = None  # anything else: the sender has moved on
        partials = stream.partials
        # A sender sends one frame after another on an arbitration id (its segments may swap places
        # within the frame, never with another frame's): a segment under another transfer id means the
        # frames being assembled under the others are over, their missing segments lost. Give them up, so
        # that none completes later, out of order, from a segment of a newer frame that happens to be
        # byte-identical to the one it lost (a last segment holding only the delimiter, say).
        for over in [k for k in partials if k != tid]:
            del partials[over]
            if stream.headed:
                self.stats.incomplete += 1
            else:  # the tail of a frame sent before this receiver listened
                self.stats.cut += 1
        if index == 0:
            stream.headed = True
        partial = partials.get(tid)
        if partial is None:
            partial = self._open(partials, tid, is_fd)
        elif partial.fd != is_fd or self._conflicts(partial, index, chunk, end >= 0):
            del partials[tid]
            self.stats.incomplete += 1
            partial = self._open(partials, tid, is_fd)
        elif partial.segments.get(index) == chunk:
            self.stats.duplicates += 1
            return b""
        partial.segments[index] = chunk
        if end >= 0:
            partial.last = index
        if partial.last is None or len(partial.segments) != partial.last + 1:
            return b""
        wire = b"".join(partial.segments[i] for i in range(partial.last + 1))
        if len(wire) > MAX_WIRE:
            del partials[tid]
            self.stats.malformed += 1
            return b""
        if not _intact(wire):
            if len(partial.segments) == 1:  # one segment joins nothing: a sender's corrupt frame
                del partials[tid]
                self.stats.malformed += 1
                return b""
            # The 2-bit transfer id wrapped: a frame that lost segments met the same id four frames on,
            # the frames between lost whole; their segments joined. Never delivered half-built: the
            # segment just heard is the newest frame's, so assembly starts again from it alone.
            self.stats.spliced += 1
            partials[tid] = _Partial({index: chunk}, index if end >= 0 else None, is_fd)
            return b""
        del partials[tid]
        stream.completed_by = (tid, index, chunk)
        if stream.delivered == (tid, wire):
            self.stats.duplicates += len(partial.segments)  # a late repeat of the frame just delivered
            return b""
        stream.delivered = (tid, wire)
        stream.completed_at = at
        self.stats.frames += 1
        return wire

    def feed_message(self, message: object) -> bytes:
        """Convenience for a python-can ``Message`` (duck-typed: no python-can import here): :meth:`admit`,
        then :meth:`feed`."""
        fields = self.admit(message)
        return b"" if fields is None else self.feed(*fields)

    def admit(self, message: object) -> Received | None:
        """The fields of a python-can ``Message`` that can be a data frame, checked; None (counted) when it
        cannot be one. Error frames (whose data is the controller's error report) and remote frames are
        ``error_frames``. A message whose fields are not a CAN frame's is ``invalid``: python-can hands
        over what a stray udp_multicast datagram says once its own check passes (an id of 901.5, a flag
        of 2), and the virtual interface whatever another thread built — none of it may raise in a
        receiver. Its ``timestamp`` is the receive time (0.0, python-can's "not set", counts as unknown;
        so does one that is not a finite number)."""
        error = _flag(getattr(message, "is_error_frame", False))
        remote = _flag(getattr(message, "is_remote_frame", False))
        is_fd = _flag(getattr(message, "is_fd", False))
        extended = _flag(getattr(message, "is_extended_id", False))
        if error is None or remote is None or is_fd is None or extended is None:
            self.stats.invalid += 1
            return None
        if error or remote:
            self.stats.error_frames += 1
            return None
        arbitration_id = getattr(message, "arbitration_id", None)
        data = getattr(message, "data", None)
        dlc = getattr(message, "dlc", None)
        if (
            not _is_int(arbitration_id)
            or not 0 <= arbitration_id < (1 << 29 if extended else 1 << 11)
            or not isinstance(data, (bytes, bytearray))
            or not (dlc is None or (_is_int(dlc) and dlc == len(data)))
        ):
            self.stats.invalid += 1
            return None
        return Received(
            arbitration_id, bytes(data), is_fd, extended, _receive_time(getattr(message, "timestamp", None))
        )

    @property
    def partial_frames(self) -> int:
        """Partial frames held now (bounded by ``window × max_streams``)."""
        return sum(len(s.partials) for s in self._streams.values())

    # ------------------------------------------------------------------ internals
    def _accepts(self, arbitration_id: int) -> bool:
        try:
            cid = CanId.parse(arbitration_id)
        except ProtocolError:
            return False
        if self.node is not None and cid.node != self.node:
            return False
        return self.direction is None or cid.direction is self.direction

    def _stream(self, arbitration_id: int) -> _Stream:
        stream = self._streams.get(arbitration_id)
        if stream is None:
            if len(self._streams) >= self.max_streams:
                _, dropped = self._streams.popitem(last=False)
                self.stats.incomplete += len(dropped.partials)
            stream = self._streams[arbitration_id] = _Stream()
        else:
            self._streams.move_to_end(arbitration_id)
        return stream

    def _open(self, partials: OrderedDict[int, _Partial], tid: int, fd: bool) -> _Partial:
        while len(partials) >= self.window:
            partials.popitem(last=False)
            self.stats.incomplete += 1
        partial = partials[tid] = _Partial(fd=fd)
        return partial

    @staticmethod
    def _conflicts(partial: _Partial, index: int, chunk: bytes, is_last: bool) -> bool:
        """A segment that cannot belong to the frame being assembled under its transfer id."""
        held = partial.segments.get(index)
        if held is not None and held != chunk:
            return True
        if partial.last is not None and (index > partial.last or (is_last and index != partial.last)):
            return True
        return is_last and any(i > index for i in partial.segments)


__all__ = [
    "CanFrame",
    "CanId",
    "CanReassembler",
    "CanSegmenter",
    "CanStats",
    "Direction",
    "MIN_WIRE",
    "PRIORITY",
    "Priority",
    "Received",
    "REPEAT_WINDOW_S",
    "max_segments",
    "segment_payload",
]
