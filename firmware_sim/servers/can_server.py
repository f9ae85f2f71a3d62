"""The board on a CAN bus: a small loop around the sans-IO :class:`Board`, like :mod:`.pty_server`.

The server is the board's end of :class:`hil.link.transports.can_bus.CanTransport` (it sends
``Direction.TO_HOST`` and accepts ``TO_BOARD`` segments for its node), so the host's transport and the
board's share one implementation of the segmentation. Real time: the board's clock is a ``WallClock``;
the loop waits in the bus's ``recv`` until the board's next absolute deadline or until a CAN frame
arrives, whichever comes first.

``url`` is the same ``can://<interface>/<channel>?node=N…`` the host opens (``firmware-sim --can
udp_multicast/239.74.163.2?port=43113`` serves ``can://udp_multicast/239.74.163.2?port=43113``).

A bus has no connection to lose: a host is there while its frames arrive, gone after a silence
(:class:`.base.HostPresence`). The statistics (:class:`.base.ServerStats`) are the pty server's, the
link-layer ``errors`` being the transport's reassembly and send failures (:meth:`CanServer.counters` has
them one by one; other nodes' traffic — ``rx_ignored``, ``rx_wrong_kind``, ``rx_undecodable``,
``rx_invalid`` (a message python-can decoded whose fields are not a frame's: a float id from a stray
datagram), ``rx_same_node``: a second board at this node id, logged by the transport, and
``rx_other_sender``: a second host at it, its frames dropped — is not the link's error, and none of it
stops the loop: only a bus that fails does, as a ``LinkError``).

Thread safety: :meth:`serve` runs in the calling thread, :meth:`start` in a daemon thread; other threads
touch the board only inside ``with server.lock:``. An error in the serving thread is stored, logged and
raised by :meth:`check` and :meth:`close` — the thread never dies silently.
"""

from __future__ import annotations

import logging

from protocol.can import Direction

from ..board import Board
from .base import BoardServer, FrameCounter, HostPresence

logger = logging.getLogger(__name__)

_MAX_WAIT_S = 0.05  # the loop looks at its stop flag at least this often
_LINK_ERRORS = ("rx_incomplete", "rx_spliced", "rx_malformed", "tx_frames_dropped", "tx_not_frames")
"""The transport's counters that are link-layer errors (ServerStats.errors is their sum)."""


class CanServer(BoardServer):
    """Serve ``board`` on the CAN bus named by ``url`` (``can://…``, or ``interface/channel?…``)."""

    def __init__(self, board: Board, url: str) -> None:
        from hil.link.transports.can_bus import CanTransport

        if "://" not in url:
            url = f"can://{url}"
        self.board = board
        self.path = url  # what the host opens (the pty server's ``path`` counterpart)
        super().__init__(f"CAN server on {url}")
        self.presence = HostPresence(self.stats)
        self._frames_out = FrameCounter()
        self.transport = CanTransport(url, sends=Direction.TO_HOST)
        self.transport.open()

    # ------------------------------------------------------------------ BoardServer
    def board_time(self) -> float:
        with self.lock:
            return self.board.now

    def _release(self) -> None:
        self.transport.close()

    def counters(self) -> dict[str, int]:
        """The bus side's segmentation counters (see ``CanTransport.counters``)."""
        return self.transport.counters()

    # ------------------------------------------------------------------ the loop, in steps
    def pump(self, now: float) -> None:
        """Run the board to ``now`` (its clock's time) and put what it said on the bus."""
        with self.lock:
            self.board.step(now)
            self.note_state(now, self.board.state)
            out = self.board.take_output()
        if out:
            self.transport.write(out)
            self.stats.bytes_out += len(out)
            self.stats.frames_out += self._frames_out.feed(out)
            self._count_errors()

    def take_in(self, timeout: float) -> bytes:
        """Feed the board whatever frames the host completed within ``timeout`` seconds (wall time: the
        bus's wait); returns them. Found none, the host is judged silent as of the look's start
        (:meth:`.base.HostPresence.tick`)."""
        looked = self.board.clock.now()
        data = self.transport.read(timeout)
        if data:
            self.stats.bytes_in += len(data)
            with self.lock:
                # Fed first: feeding runs the board to its clock's now, the time the bytes are taken. Heard
                # at the board's time before it, a host whose frames waited on the bus while this process
                # was stopped (SIGSTOP, a long pause) would count as silent for the whole stall and be
                # reported gone, then back, though it never left.
                self.board.feed(data)
                self.presence.heard(self.board.now)
                self.note_state(self.board.now, self.board.state)
        else:
            with self.lock:
                self.presence.tick(looked)
        self.stats.frames_in = self.transport.counters()["rx_frames"]
        self._count_errors()
        return data

    def _count_errors(self) -> None:
        counters = self.transport.counters()
        self.stats.errors = sum(counters[k] for k in _LINK_ERRORS)

    def serve(self, duration: float | None = None) -> None:
        """Run until :meth:`stop` (or for ``duration`` seconds of board time)."""
        board = self.board
        clock = board.clock
        end = None if duration is None else clock.now() + duration
        while not self.stopping():  # a bus closed under the loop raises LinkError: never a silent end
            now = clock.now()
            self.pump(now)
            if end is not None and now >= end:
                return
            with self.lock:
                wait = board.next_deadline() - clock.now()
            wait = min(max(wait, 0.0), _MAX_WAIT_S)
            if end is not None:
                wait = min(wait, max(end - clock.now(), 0.0))
            self.stats.loops += 1
            self.take_in(wait)
