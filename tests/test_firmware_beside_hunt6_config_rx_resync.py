"""The emulator's UART receive ring follows the firmware's rule after an overflow (firmware/src/uart.c): bytes
go in again only from a frame delimiter on, once the main loop has freed half the ring, so the frame the
overflow cut ends at that delimiter as one bad frame and the next one is taken whole or not at all.

The emulator took bytes again as soon as there was room: the head of the cut frame was joined to the tail
of whatever came next. Of identical frames (a repeated heartbeat, a retransmitted command) cut at the same
place that is a valid frame the host never sent whole — counted as received, acted on — where the
firmware counts one bad frame; of other frames, a bad frame of another kind and length than the board's.
"""

from __future__ import annotations

import hypothesis.strategies as st
from conformance.host import heartbeat, lockstep
from hypothesis import assume, example, given, settings

from firmware_sim.board.config import BoardConfig
from firmware_sim.board.link import BoardLink
from protocol.frame import Deframer, encode_frame
from protocol.messages import Telemetry

UART_RX_SIZE = 384  # firmware/include/uart.h: the firmware's ring, UART_RX_SIZE - 1 bytes held


class FirmwareRing:
    """firmware/src/uart.c's receive interrupt and main-loop read, transcribed byte for byte: the oracle
    the emulator's ring is held to (``size`` slots, ``size - 1`` bytes held)."""

    def __init__(self, size: int) -> None:
        self.size, self.buf, self.head, self.tail = size, [0] * size, 0, 0
        self.resync, self.overflow = False, 0

    def isr(self, b: int) -> None:
        nxt = (self.head + 1) % self.size
        if nxt == self.tail:
            self.overflow += 1
            self.resync = True
            return
        if self.resync:
            if b != 0 or (self.tail + self.size - nxt) % self.size < self.size // 2:
                self.overflow += 1
                return
            self.resync = False
        self.buf[self.head] = b
        self.head = nxt

    def read_all(self) -> bytes:
        out = bytearray()
        while self.tail != self.head:
            out.append(self.buf[self.tail])
            self.tail = (self.tail + 1) % self.size
        return bytes(out)


FRAME = encode_frame(heartbeat(), seq=9)
wire = st.lists(  # chunks of frames, cut anywhere, with the main loop reading (or not) between them
    st.tuples(
        st.integers(1, 12).flatmap(lambda n: st.integers(0, n * len(FRAME)).map(lambda k: (n, k))),
        st.booleans(),
    ),
    min_size=1,
    max_size=12,
)


@settings(max_examples=400, deadline=None)
@given(size=st.sampled_from([65, 97, 128, UART_RX_SIZE]), chunks=wire)
@example(size=UART_RX_SIZE, chunks=[((20, 0), True), ((20, 7), True)])
def test_the_emulators_ring_takes_and_drops_exactly_the_bytes_the_firmwares_does(size, chunks):
    """Any sequence of bursts (whole frames, or starting part-way into one), read out or not between them:
    what the emulator's ring hands the deframer, and what it counts lost, is what the firmware's does."""
    emulator, firmware = BoardLink(rx_capacity=size - 1, tx_capacity=4096), FirmwareRing(size)
    firmware_deframer = Deframer()  # the firmware's bytes through a deframer of their own
    for (frames, skip), read in chunks:
        burst = (FRAME * frames)[skip:]
        emulator.receive(burst)
        for b in burst:
            firmware.isr(b)
        assert emulator.stats.rx_overflow == firmware.overflow
        if read:
            emulator.drain()
            firmware_deframer.feed(firmware.read_all())
            ours, theirs = emulator.deframer.counters, firmware_deframer.counters
            assert (ours.bytes, ours.frames, ours.bad) == (theirs.bytes, theirs.frames, theirs.bad)


@settings(max_examples=120, deadline=None)
@given(capacity=st.integers(64, 600), extra=st.integers(1, 10), after=st.integers(1, 4))
@example(capacity=100, extra=3, after=2)
def test_a_frame_cut_by_an_overflow_is_one_bad_frame_never_joined_to_a_later_one(capacity, extra, after):
    """The lockstep board, its ring of ``capacity`` bytes flooded by one burst of identical heartbeats that
    overflows mid-frame, then (after the main loop has read the ring) the rest of a frame and ``after``
    whole ones: its telemetry counts the cut frame as one bad frame and only the whole frames as received."""
    cut = capacity % len(FRAME)
    assume(cut != 0)
    after = min(after, (capacity - len(FRAME)) // len(FRAME))  # the second send fits the emptied ring
    board, clock, host = lockstep(BoardConfig(rx_buffer_bytes=capacity))
    host.handshake()
    host.keepalive = None
    before = host.wait_type(Telemetry, 0.2)
    host.send_raw(FRAME * (capacity // len(FRAME) + extra))
    host.poll(0.003)  # the main loop reads the ring: its whole frames and the cut one's head
    host.send_raw(FRAME[cut:] + FRAME * after)
    now = host.wait_type(Telemetry, 0.2, lambda t: t.time_ms > before.time_ms + 5)
    whole = capacity // len(FRAME) + after
    # the delimiter the resync takes ends the cut frame: one bad frame, or, cut just before its own
    # delimiter, the frame itself
    expected = (whole + 1, 0) if cut == len(FRAME) - 1 else (whole, 1)
    got = (now.rx_frames - before.rx_frames, now.rx_bad - before.rx_bad)
    assert got == expected, f"cut at byte {cut} of {len(FRAME)}: (frames, bad) {got}, not {expected}"
    assert board.link.stats.rx_overflow == len(FRAME) * extra - cut + len(FRAME) - cut - 1
