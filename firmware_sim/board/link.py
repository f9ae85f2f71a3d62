"""The board's end of the serial link: the UART receive ring, the deframer, the framer with a bounded
transmit buffer, and the duplicate filter for reliable commands.

The UART interrupt keeps receiving while the main loop is busy (or hung): bytes land in a ring of
``rx_capacity`` bytes and the overflow is dropped and counted, as on the MCU, which then takes bytes again
only from a frame delimiter on, once half the ring is free (see :meth:`BoardLink.receive`). Reliable
commands are answered once per ``(msg_id, seq)``: a retransmission (RETRANSMIT flag, same id, seq and
payload) of a command already executed gets the same ACK/NACK again without running the command twice. A
``Hello`` forgets those answers (the handshake does it) and begins the host's numbering afresh for the
counters: a restarted host's frames, numbered from 0 again, are neither answered from its predecessor's
cache nor counted as lost.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from protocol.frame import MAX_ENCODED, Deframer, Event, Frame, Framer
from protocol.messages import CalibrationData, Flags, Heartbeat, Hello, Telemetry

_RENUMBERED_BY = (Hello.MSG_ID,)
"""A host's ``Hello`` begins its numbering afresh (a restarted host starts at 0 again): the jump to it is
no sequence gap in ``Telemetry.seq_gaps`` (docs/protocol.md, "Counters")."""


SENT_AGAIN = (Telemetry.MSG_ID, Heartbeat.MSG_ID, CalibrationData.MSG_ID)
"""What the board sends again anyway (the next telemetry or heartbeat is newer; a download fragment is
retried until acknowledged): it is not queued into the transmit buffer's last :data:`SAID_ONCE_ROOM`
bytes, which stay for answers and Logs — the firmware's rule (firmware/src/report.c)."""
SAID_ONCE_ROOM = MAX_ENCODED + 1 + 64
"""A HelloReply (the largest frame on the wire) and a few Acks."""


@dataclass
class LinkStats:
    rx_overflow: int = 0  # bytes lost because the receive ring was full
    tx_dropped: int = 0  # frames not sent because the transmit buffer was full
    duplicates: int = 0  # retransmitted reliable commands answered from the cache
    ignored: int = 0  # valid frames the board does not act on (wrong state, wrong direction)


class BoardLink:
    def __init__(self, rx_capacity: int, tx_capacity: int, dedup_entries: int = 32) -> None:
        self.rx_capacity = rx_capacity
        self.tx_capacity = tx_capacity
        self.deframer = Deframer(_RENUMBERED_BY)
        self.framer = Framer()
        self.stats = LinkStats()
        self._rx = bytearray()
        self._resyncing = False  # the ring overflowed: bytes are dropped up to the next frame delimiter
        # bytes free in the ring at which a delimiter is taken again: half the firmware's ring of
        # UART_RX_SIZE slots, which hold UART_RX_SIZE - 1 bytes (uart.c)
        self._resync_free = (rx_capacity + 1) // 2
        self._tx = bytearray()
        self._answers: OrderedDict[tuple[int, int], tuple[Any, Any]] = OrderedDict()
        self._dedup_entries = dedup_entries

    def reset(self) -> None:
        """MCU reset: the rings are cleared, sequence numbers restart, the duplicate cache is forgotten."""
        self._rx.clear()
        self._resyncing = False
        self._tx.clear()
        self.deframer = Deframer(_RENUMBERED_BY)  # the MCU's counters restart with it
        self.framer = Framer()
        self._answers.clear()

    # ------------------------------------------------------------------ receive
    def receive(self, data: bytes) -> None:
        """Bytes from the wire into the UART ring (the ISR's job, firmware/src/uart.c's rule).

        Bytes that find the ring full are dropped and counted (``rx_overflow``); after that, bytes go in
        again only from a frame delimiter on, and only once the main loop has freed half the ring, and the
        ones passed over are counted too. The delimiter ends the cut frame in the ring (one bad frame) and
        the next frame is taken whole or not at all. Taking bytes again as soon as there was room joined
        the cut frame's head to the tail of a later frame: of two identical frames (a retransmission, a
        repeated heartbeat) cut at the same place, a valid frame the host never sent whole."""
        free = self.rx_capacity - len(self._rx)  # constant until the delimiter: nothing goes in before it
        if self._resyncing:
            delimiter = data.find(0) if free >= self._resync_free else -1
            if delimiter < 0:
                self.stats.rx_overflow += len(data)
                return
            self.stats.rx_overflow += delimiter
            data = data[delimiter:]
            self._resyncing = False
        if len(data) > free:
            self.stats.rx_overflow += len(data) - free
            data = data[:free]
            self._resyncing = True
        self._rx += data

    @property
    def rx_pending(self) -> bool:
        return bool(self._rx)

    def drain(self) -> list[Event]:
        """The main loop's job: everything in the ring through the deframer."""
        if not self._rx:
            return []
        data = bytes(self._rx)
        self._rx.clear()
        return self.deframer.feed(data)

    # ------------------------------------------------------------------ transmit
    def send(self, message: Any, flags: int = 0, seq: int | None = None) -> int | None:
        """Queue one frame; returns its sequence number, or None if the transmit buffer was full."""
        seq, data = self.framer.encode(message, flags, seq)
        room = self.tx_capacity - (SAID_ONCE_ROOM if message.MSG_ID in SENT_AGAIN else 0)
        if len(self._tx) + len(data) > room:
            self.stats.tx_dropped += 1
            return None
        self._tx += data
        return seq

    def take(self) -> bytes:
        data = bytes(self._tx)
        self._tx.clear()
        return data

    @property
    def tx_pending(self) -> int:
        return len(self._tx)

    # ------------------------------------------------------------------ reliable commands
    def cached_answer(self, frame: Frame) -> Any | None:
        """The answer already given to this retransmitted command, or None if it must be executed."""
        if not frame.flags & Flags.RETRANSMIT:
            return None
        hit = self._answers.get((frame.msg_id, frame.seq))
        if hit is None or hit[0] != frame.message:
            return None
        self.stats.duplicates += 1
        return hit[1]

    def remember_answer(self, frame: Frame, answer: Any) -> None:
        key = (frame.msg_id, frame.seq)
        self._answers[key] = (frame.message, answer)
        self._answers.move_to_end(key)
        while len(self._answers) > self._dedup_entries:
            self._answers.popitem(last=False)

    def forget_answers(self) -> None:
        self._answers.clear()
