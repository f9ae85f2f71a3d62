"""Carrying a calibration set over the link: cut into ``CalibrationData`` fragments, put back together.

A set of ``total_len`` bytes travels as ``count = max(1, ceil(total_len / MAX_CALIBRATION_CHUNK))``
fragments ``index = 0 .. count-1``; every fragment but the last carries exactly ``MAX_CALIBRATION_CHUNK``
bytes, and all carry the same ``unit``, ``transfer_id``, ``count``, ``total_len`` and ``set_crc``
(CRC-16/CCITT-FALSE of the whole set). Fragments are reliable messages: each is acknowledged, and a lost
acknowledgement makes the sender retry, so the receiver sees duplicates; they are harmless.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ..crc import crc16_ccitt_false
from ..errors import CalibrationError, FieldRangeError
from ..messages import MAX_CALIBRATION_CHUNK, MAX_UNITS, CalibrationData

MAX_TRANSFER_BYTES = 255 * MAX_CALIBRATION_CHUNK


def fragment(unit: int, transfer_id: int, data: bytes) -> list[CalibrationData]:
    """``data`` (one unit's set) as CalibrationData fragments, in order."""
    if not 0 <= unit < MAX_UNITS:
        raise FieldRangeError("CalibrationData", "unit", unit)
    if not 0 <= transfer_id <= 255:
        raise FieldRangeError("CalibrationData", "transfer_id", transfer_id)
    data = bytes(data)
    if len(data) > MAX_TRANSFER_BYTES:
        raise FieldRangeError("CalibrationData", "total_len", len(data))
    count = max(1, -(-len(data) // MAX_CALIBRATION_CHUNK))
    crc = crc16_ccitt_false(data)
    return [
        CalibrationData(
            unit=unit,
            transfer_id=transfer_id,
            index=i,
            count=count,
            total_len=len(data),
            set_crc=crc,
            chunk=data[i * MAX_CALIBRATION_CHUNK : (i + 1) * MAX_CALIBRATION_CHUNK],
        )
        for i in range(count)
    ]


@dataclass
class ReassemblyCounters:
    fragments: int = 0  # fragments fed
    duplicates: int = 0  # repeats of a fragment already held (or of the set just completed)
    restarts: int = 0  # an unfinished transfer abandoned because another one started
    completed: int = 0  # sets returned
    failed: int = 0  # transfers rejected (bad header, inconsistent fragment, length or CRC mismatch)


@dataclass(frozen=True)
class _Header:
    unit: int
    transfer_id: int
    count: int
    total_len: int
    set_crc: int

    @classmethod
    def of(cls, m: CalibrationData) -> _Header:
        return cls(m.unit, m.transfer_id, m.count, m.total_len, m.set_crc)


class Reassembler:
    """Collects the fragments of one transfer at a time; memory is bounded by ``max_len`` bytes.

    ``feed`` returns ``(unit, data)`` when a set is complete and its CRC checks, else None. A fragment of
    another ``(unit, transfer_id)`` abandons the unfinished transfer and starts the new one. Repeats of a
    fragment already held, or of the transfer just completed, are ignored (until :meth:`forget`: a
    receiver that refuses the completed set must forget it). A malformed fragment, one that
    contradicts the transfer's header, or a finished set whose length or CRC is wrong raises
    :class:`CalibrationError` and drops the transfer.
    """

    def __init__(self, max_len: int = MAX_TRANSFER_BYTES) -> None:
        self.max_len = max_len
        self.counters = ReassemblyCounters()
        self._header: _Header | None = None
        self._chunks: dict[int, bytes] = {}
        self._done: _Header | None = None

    def reset(self) -> None:
        """Forget any unfinished transfer."""
        self._header = None
        self._chunks = {}

    def forget(self) -> None:
        """Forget every transfer, the one just completed too: its repeat is then a new transfer, judged
        anew. For a receiver that refused the set :meth:`feed` returned (so a host sending it again is not
        told it was taken), and at a new session (a restarted host numbers its transfers from 1 again)."""
        self.reset()
        self._done = None

    @property
    def in_progress(self) -> tuple[int, int] | None:
        """(unit, transfer_id) of the unfinished transfer, if any."""
        h = self._header
        return None if h is None else (h.unit, h.transfer_id)

    def feed(self, msg: CalibrationData) -> tuple[int, bytes] | None:
        self.counters.fragments += 1
        header = _Header.of(msg)
        where = f"calibration transfer {msg.transfer_id} (unit {msg.unit}), fragment {msg.index}/{msg.count}"
        if header == self._done:
            self.counters.duplicates += 1
            return None
        try:
            self._check_fragment(msg, where)
        except CalibrationError:
            self._fail()
            raise
        current = self._header
        if current is None or (current.unit, current.transfer_id) != (msg.unit, msg.transfer_id):
            if current is not None:
                self.counters.restarts += 1
            self._header, self._chunks, self._done = header, {}, None
        elif header != current:
            self._fail()
            raise CalibrationError(
                f"header (count {msg.count}, total_len {msg.total_len}, set_crc {msg.set_crc:#06x})"
                f" contradicts the transfer's (count {current.count}, total_len {current.total_len}, set_crc"
                f" {current.set_crc:#06x})",
                where,
            )
        held = self._chunks.get(msg.index)
        if held is not None:
            if held != msg.chunk:
                self._fail()
                raise CalibrationError("a repeat of this fragment carries different bytes", where)
            self.counters.duplicates += 1
            return None
        self._chunks[msg.index] = bytes(msg.chunk)
        if len(self._chunks) < msg.count:
            return None
        return self._finish(header, where)

    def _check_fragment(self, msg: CalibrationData, where: str) -> None:
        if msg.total_len > self.max_len:
            raise CalibrationError(
                f"total_len {msg.total_len} exceeds this receiver's {self.max_len} bytes", where
            )
        want_count = max(1, -(-msg.total_len // MAX_CALIBRATION_CHUNK))
        if msg.count != want_count:
            raise CalibrationError(
                f"count {msg.count} does not fit total_len {msg.total_len} (needs {want_count})", where
            )
        if not msg.index < msg.count:
            raise CalibrationError(f"index {msg.index} is not below count {msg.count}", where)
        last = msg.total_len - MAX_CALIBRATION_CHUNK * (msg.count - 1)
        want = last if msg.index == msg.count - 1 else MAX_CALIBRATION_CHUNK
        if len(msg.chunk) != want:
            raise CalibrationError(f"chunk of {len(msg.chunk)} bytes, expected {want}", where)

    def _finish(self, header: _Header, where: str) -> tuple[int, bytes]:
        data = b"".join(self._chunks[i] for i in range(header.count))
        self.reset()
        crc = crc16_ccitt_false(data)
        if len(data) != header.total_len or crc != header.set_crc:
            self.counters.failed += 1
            raise CalibrationError(
                f"set of {len(data)} bytes with CRC {crc:#06x}; the transfer announced"
                f" {header.total_len} bytes with CRC {header.set_crc:#06x}",
                where,
            )
        self._done = header
        self.counters.completed += 1
        return header.unit, data

    def _fail(self) -> None:
        self.counters.failed += 1
        self.reset()


def reassemble(fragments: Sequence[CalibrationData]) -> tuple[int, bytes]:
    """The set carried by ``fragments`` (any order, duplicates allowed); CalibrationError if incomplete."""
    r = Reassembler()
    for f in fragments:
        done = r.feed(f)
        if done is not None:
            return done
    raise CalibrationError(f"incomplete: {len(r._chunks)} distinct fragments fed", "calibration transfer")
