"""The board on a CAN bus: a small loop around the sans-IO :class:`Board`, like :mod:`.pty_server`.

The server is the board's end of :class:`hil.link.transports.can_bus.CanTransport` (it sends
``Direction.TO_HOST`` and accepts ``TO_BOARD`` segments for its node), so the host's transport and the
board's share one implementation of the segmentation. Real time: the board's clock is a ``WallClock``;
the loop waits in the bus's ``recv`` until the board's next absolute deadline or until a CAN frame
arrives, whichever comes first.

``url`` is the same ``can://<interface>/<channel>?node=N…`` the host opens (``firmware-sim --can
udp_multicast/239.74.163.2?port=43113`` serves ``can://udp_multicast/239.74.163.2?port=43113``).

Thread safety: :meth:`serve` runs in the calling thread, :meth:`start` in a daemon thread; other threads
touch the board only inside ``with server.lock:``. An error in the serving thread is stored, logged and
raised by :meth:`check` and :meth:`close` — the thread never dies silently.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from types import TracebackType

from hil.threads import ThreadError
from protocol.can import Direction

from ..board import Board

logger = logging.getLogger(__name__)

_MAX_WAIT_S = 0.05  # the loop looks at its stop flag at least this often


@dataclass
class CanServerStats:
    bytes_in: int = 0  # wire bytes reassembled from the bus and fed to the board
    bytes_out: int = 0  # wire bytes the board produced, sent as segments
    dropped_out: int = 0  # always 0: the bus takes every frame or the transport counts it (tx_*)
    loops: int = 0


class CanServer:
    """Serve ``board`` on the CAN bus named by ``url`` (``can://…``, or ``interface/channel?…``)."""

    def __init__(self, board: Board, url: str) -> None:
        from hil.link.transports.can_bus import CanTransport

        if "://" not in url:
            url = f"can://{url}"
        self.board = board
        self.lock = threading.RLock()
        self.stats = CanServerStats()
        self.transport = CanTransport(url, sends=Direction.TO_HOST)
        self.transport.open()
        self.path = url  # what the host opens (the pty server's ``path`` counterpart)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._thread_error = ThreadError(f"CAN server on {self.path} failed")

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> CanServer:
        """Serve in a daemon thread; :meth:`close` stops it. An error in the thread is re-raised there."""
        if self._thread is None:
            self._thread = threading.Thread(
                target=self._run_thread, name=f"can-server {self.path}", daemon=True
            )
            self._thread.start()
        return self

    def _run_thread(self) -> None:
        with self._thread_error.caught(logger, "CAN server thread failed"):  # raised by close()/check()
            self.serve()

    def stop(self) -> None:
        self._stop.set()

    def check(self) -> None:
        """Raise the serving thread's error, if it had one."""
        self._thread_error.check()

    def close(self) -> None:
        """Stop serving and release the bus. Idempotent."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)
        self.transport.close()
        self.check()

    def __enter__(self) -> CanServer:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def counters(self) -> dict[str, int]:
        """The bus side's segmentation counters (see ``CanTransport.counters``)."""
        return self.transport.counters()

    # ------------------------------------------------------------------ the loop
    def serve(self, duration: float | None = None) -> None:
        """Run until :meth:`stop` (or for ``duration`` seconds of board time)."""
        board, transport = self.board, self.transport
        clock = board.clock
        end = None if duration is None else clock.now() + duration
        while not self._stop.is_set():  # a bus closed under the loop raises LinkError: never a silent end
            with self.lock:
                now = clock.now()
                board.step(now)
                out = board.take_output()
                wait = board.next_deadline() - clock.now()
            if out:
                transport.write(out)
                self.stats.bytes_out += len(out)
            if end is not None and now >= end:
                return
            wait = min(max(wait, 0.0), _MAX_WAIT_S)
            if end is not None:
                wait = min(wait, max(end - clock.now(), 0.0))
            self.stats.loops += 1
            data = transport.read(wait)
            if data:
                self.stats.bytes_in += len(data)
                with self.lock:
                    board.feed(data)
