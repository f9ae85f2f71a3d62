"""The host's own frames coming back, sans-IO: :class:`WrittenFrames` remembers what the host wrote lately
and tells a received frame that is one of them, byte for byte.

Why: a port that echoes what is written to it — a loopback plug, TX joined to RX, an RS-485 or
half-duplex adapter that hears its own transmitter — hands the host its own frames as if the board had
sent them. Some are of kinds only the host sends (Hello, Arm, setpoints) and are easily told; others are
of kinds both ends send: a ``Heartbeat`` (the host's carries its own clock and state 0, which is BOOT:
taken as the board's, its uptime "went back" — a spurious board reset, a new handshake, the armed board
disarmed), an ``Ack`` or ``Nack`` (the host's answers to a download's fragments: taken as answers to the
host's own commands), a ``CalibrationData`` (an upload's fragment, taken as a download's). And every one
of them, taken as heard from the board, kept a silent board looking alive. A frame that comes back is the
very bytes the host wrote, so it is told by re-encoding it (the codec round-trips exactly) and looking the
wire bytes up among those written in the last :data:`ECHO_WINDOW_S` (at most :data:`ECHO_CAPACITY` of
them: memory stays bounded whatever the host writes). A board's own frame is the same bytes only if it
carries the same sequence number, flags and fields — for a Heartbeat its uptime equal to the host's clock
in ms and its state BOOT, in the same window: not a case worth a false "echo".
"""

from __future__ import annotations

from collections import Counter, deque

from protocol.errors import HilError
from protocol.frame import Frame, encode_frame
from protocol.messages import PROTOCOL_VERSION

ECHO_WINDOW_S = 2.0
"""Host time (s) a written frame is remembered: an echo comes back within milliseconds, or a host paused
under load reads it late, but not seconds later."""
ECHO_CAPACITY = 1024
"""Frames remembered at most: two seconds of setpoints at 200 Hz, heartbeats and commands besides."""


class WrittenFrames:
    """The wire bytes of the frames the host wrote in the last ``window_s`` (at most ``capacity``)."""

    def __init__(self, window_s: float = ECHO_WINDOW_S, capacity: int = ECHO_CAPACITY) -> None:
        self.window_s = window_s
        self.capacity = capacity
        self._order: deque[tuple[float, bytes]] = deque()
        self._held: Counter[bytes] = Counter()

    def wrote(self, data: bytes, now: float) -> None:
        """``data`` (whole frames, each ending in its only 0x00) was written at ``now``."""
        start = 0
        while True:
            end = data.find(0, start)
            if end < 0:
                break
            wire = data[start : end + 1]
            start = end + 1
            self._order.append((now, wire))
            self._held[wire] += 1
        while len(self._order) > self.capacity:
            self._forget()

    def came_back(self, frame: Frame, now: float) -> bool:
        """Whether ``frame`` is, byte for byte, one the host wrote in the last ``window_s``. Not consumed:
        an adapter that echoes twice hands back the same frame twice, and the second copy is no more the
        board's than the first."""
        order = self._order
        while order and order[0][0] < now - self.window_s:
            self._forget()
        if not self._held or frame.version != PROTOCOL_VERSION:
            return False
        try:
            wire = encode_frame(frame.message, frame.seq, int(frame.flags))
        except HilError:  # a decoded frame always encodes; if one does not, it is not ours
            return False
        return wire in self._held

    def _forget(self) -> None:
        _, wire = self._order.popleft()
        left = self._held[wire] - 1
        if left:
            self._held[wire] = left
        else:
            del self._held[wire]
