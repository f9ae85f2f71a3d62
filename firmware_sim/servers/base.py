"""What every far-side server is: one statistics type, one notion of host presence, one lifecycle.

A *server* puts a board behind something a host opens: a pty (:mod:`.pty_server`), a CAN bus
(:mod:`.can_server`), the C firmware under simavr (:mod:`firmware_sim.avr.serve`). ``firmware-sim``'s
status lines (:class:`firmware_sim.status.StatusLines`) and the tests read every one of them the same
way, through :class:`BoardServer`; an attribute one server lacks is a type error there, found by mypy,
not an ``AttributeError`` in a status thread at run time.

**Host presence.** A pty with its slave held open and a CAN bus have no connection to lose: a host that
closes the port or leaves the bus simply goes quiet. So every server judges presence the same way
(:class:`HostPresence`): a host *arrives* with the first bytes after an absence and is *gone* after
:data:`HOST_SILENCE_S` of board time without a byte — or at once, where the transport says so (the pty's
master reading EIO while nobody holds the slave). ``reconnects`` counts the arrivals after the first.
"""

from __future__ import annotations

import abc
import logging
import threading
from collections import deque
from dataclasses import asdict, dataclass
from types import TracebackType
from typing import Self

from hil.threads import ThreadError
from protocol.messages import BoardState

HOST_SILENCE_S = 1.0
"""Board seconds without a byte from the host after which it counts as gone: four times the board's
default link timeout (0.25 s), so a host that merely stopped streaming setpoints for a moment (a
failsafe test) is not reported as having left, while one that closed the port is, within a second."""


TRANSITIONS_KEPT = 256
"""State changes a server keeps for its status reader between two looks (a tenth of a second apart: a
board cannot change state that often but through a fault, and then the newest are what matter)."""


@dataclass
class ServerStats:
    """A server's link statistics, the same fields on every transport (counts since the server started).

    ``bytes_in``/``bytes_out``: wire bytes taken from the host / put on the link for it. ``frames_in``/
    ``frames_out``: wire frames (a 0x00 delimiter after at least one byte) among them. ``dropped_out``:
    bytes of the board's output discarded because no host could take them (a UART's lost bytes: the pty
    full or no host on it). ``errors``: what the link layer itself found wrong and discarded — CAN
    segments that never made a frame, spliced or malformed ones, sends that timed out, written bytes that
    were not a frame; a pty has no link layer of its own, so it counts none (a damaged frame is the
    board's deframer's business: ``Telemetry.rx_bad``). ``host_present``: a host is on the link now;
    ``host_gone``: times one left; ``reconnects``: times one came back after leaving. ``loops``: passes
    of the serving loop."""

    bytes_in: int = 0
    bytes_out: int = 0
    frames_in: int = 0
    frames_out: int = 0
    dropped_out: int = 0
    errors: int = 0
    host_present: bool = False
    host_gone: int = 0
    reconnects: int = 0
    loops: int = 0

    def as_dict(self) -> dict[str, int | bool]:
        return asdict(self)


class FrameCounter:
    """Counts wire frames in a byte stream fed in any chunking: a 0x00 that ends at least one other byte
    (idle 0x00 fill between frames counts nothing)."""

    __slots__ = ("frames", "_open")

    def __init__(self) -> None:
        self.frames = 0
        self._open = False  # bytes since the last delimiter

    def feed(self, data: bytes | bytearray) -> int:
        """Take ``data``; returns how many frames it ended."""
        ended = 0
        for part in bytes(data).split(b"\x00")[:-1]:
            if part or self._open:
                ended += 1
            self._open = False
        if data and data[-1] != 0:
            self._open = True
        self.frames += ended
        return ended


class HostPresence:
    """Whether a host is on the link, from when its bytes arrive (board seconds); see the module
    docstring. Writes into ``stats`` (``host_present``, ``host_gone``, ``reconnects``)."""

    def __init__(self, stats: ServerStats, silence_s: float = HOST_SILENCE_S) -> None:
        self.stats = stats
        self.silence_s = silence_s
        self.last_heard: float | None = None  # board time of the host's last bytes
        self._arrivals = 0

    def heard(self, now: float) -> None:
        """Bytes from the host arrived at board time ``now``."""
        self.last_heard = now
        if not self.stats.host_present:
            self.stats.host_present = True
            self._arrivals += 1
            self.stats.reconnects = self._arrivals - 1

    def tick(self, now: float) -> None:
        """The link was looked at and found quiet: a host silent for ``silence_s`` by board time ``now``
        is gone. ``now`` is taken *before* that look, never after it: a process stalled (SIGSTOP, a long
        pause) between a look and this judgement would otherwise count the stall as silence though the
        host's bytes waited unread, and report a host gone (then back) that never left."""
        heard = self.last_heard
        if self.stats.host_present and heard is not None and now - heard >= self.silence_s:
            self.left()

    def left(self) -> None:
        """The transport says no host is there (a pty's master reading EIO)."""
        if self.stats.host_present:
            self.stats.host_present = False
            self.stats.host_gone += 1


class BoardServer(abc.ABC):
    """A board served to a host on some link: the lifecycle every server shares (serve in the calling
    thread or a daemon thread, stop, idempotent close, a thread's error raised by :meth:`check` and
    :meth:`close`), its :class:`ServerStats` and what the status lines read of its board.

    Subclasses write :meth:`serve` (the loop; it returns when :meth:`stopping` or at the end of its
    duration; it calls :meth:`note_state` as the board runs), :meth:`_release` (close the link) and
    :meth:`board_time`."""

    path: str
    """What the host opens: a pty path, a ``can://`` URL."""

    def __init__(self, describe: str) -> None:
        self.lock = threading.RLock()
        """Held while the server touches the board; other threads take it to do the same."""
        self.stats = ServerStats()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._describe = describe
        self._thread_error = ThreadError(f"{describe} failed")
        self._state: BoardState | None = None
        self._transitions: deque[tuple[float, BoardState]] = deque(maxlen=TRANSITIONS_KEPT)

    # ------------------------------------------------------------------ what the status lines read
    @abc.abstractmethod
    def board_time(self) -> float:
        """The board's clock now (s)."""

    def note_state(self, now: float, state: BoardState | None) -> None:
        """The serving loop's look at the board's state at board time ``now``, after the board ran or took
        the host's bytes: a change is kept for :meth:`take_transitions` — every one, however brief (an
        Arm and a Disarm within one status period), where a reader sampling the state now and then
        would miss it."""
        if state is not None and state != self._state:
            self._state = state
            self._transitions.append((now, state))

    def take_transitions(self) -> list[tuple[float, BoardState]]:
        """The state changes noted since the last call, oldest first: (board time s, new state). At most
        :data:`TRANSITIONS_KEPT` are kept between calls (the oldest go first)."""
        out = []
        while self._transitions:
            out.append(self._transitions.popleft())
        return out

    # ------------------------------------------------------------------ lifecycle
    @abc.abstractmethod
    def serve(self, duration: float | None = None) -> None:
        """Run in the calling thread until :meth:`stop` (or for ``duration`` seconds of board time)."""

    @abc.abstractmethod
    def _release(self) -> None:
        """Close the link (idempotent); the serving loop has stopped."""

    def stopping(self) -> bool:
        return self._stop.is_set()

    def start(self) -> Self:
        """Serve in a daemon thread; :meth:`close` stops it. An error in the thread is re-raised there."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run_thread, name=self._describe, daemon=True)
            self._thread.start()
        return self

    def _run_thread(self) -> None:
        with self._thread_error.caught(logging.getLogger(type(self).__module__), f"{self._describe} failed"):
            self.serve()

    def stop(self) -> None:
        self._stop.set()

    def check(self) -> None:
        """Raise the serving thread's error, if it had one."""
        self._thread_error.check()

    def close(self) -> None:
        """Stop serving and release the link. Idempotent; raises the serving thread's error."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)
        self._release()
        self.check()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
