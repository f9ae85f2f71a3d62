"""The board behind a real pseudo-terminal: a small select() loop around the sans-IO :class:`Board`.

The server owns the pty's master side; the host opens the slave path (``/dev/pts/N``) with pyserial like
any serial port. Real time: the board's clock is a ``WallClock`` and the loop sleeps in ``select`` until
the board's next absolute deadline or until bytes arrive, whichever comes first.

The host may come and go. By default the server keeps its own descriptor of the slave open, so the pty
never dies when the host closes it: the host simply reopens the path (pyserial flushes what the board
sent meanwhile). With ``hold_slave=False`` the master reads EIO while no host has the slave open; the
server then treats the host as absent — drops what the board sends, polls for its return — and never
crashes. Output that the pty cannot take (the host not reading) is dropped and counted, as a UART would.
Whether a host is there is judged as on every transport (:mod:`.base`): its bytes arriving, its silence,
and — without a held slave — EIO at once.

Thread safety: :meth:`serve` runs the loop in the calling thread; :meth:`start` runs it in a daemon
thread. Other threads must touch the board only inside ``with server.lock:`` (fault injection,
reading the timeline).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import select
import termios
import time
import tty
from pathlib import Path

from protocol.errors import LinkError

from ..board import Board
from .base import BoardServer, FrameCounter, HostPresence

logger = logging.getLogger(__name__)

_MAX_WAIT_S = 0.05  # the loop looks at its stop flag at least this often
_ABSENT_POLL_S = 0.02  # with the host gone (EIO), look for its return this often
_OUT_LIMIT = 4096  # bytes held back while the pty is full, like a UART ring (older ones are dropped)
LINK_CHECK_S = 0.5
"""How often (wall seconds) the serving loop looks that its ``link`` is still there, and makes it again if
it went (removed by hand, by a cleaner of /tmp, by another server's exit): a host that reconnects through
the link finds the board within this, not never."""


class PtyServer(BoardServer):
    """Serve ``board`` on a new pty. ``link`` (optional) is a symlink kept pointing at the slave path."""

    def __init__(
        self, board: Board, link: str | os.PathLike[str] | None = None, hold_slave: bool = True
    ) -> None:
        self.board = board
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline, even before the host sets its own modes
        attrs = termios.tcgetattr(slave)
        attrs[3] &= ~termios.ECHO
        termios.tcsetattr(slave, termios.TCSANOW, attrs)
        os.set_blocking(master, False)
        self.path = os.ttyname(slave)
        super().__init__(f"pty server on {self.path}")
        self.presence = HostPresence(self.stats)
        self._frames_in, self._frames_out = FrameCounter(), FrameCounter()
        self._master: int | None = master
        self._slave: int | None = slave
        if not hold_slave:
            os.close(slave)
            self._slave = None
        self._out = bytearray()
        self._host_absent = False  # the master reads EIO: nobody holds the slave (only without hold_slave)
        self.link: Path | None = None
        self.link_remade = 0  # times the link was found gone while serving and made again
        self._link_taken_said = False  # the link was found pointing elsewhere, and that was logged
        self._next_link_check = time.monotonic() + LINK_CHECK_S
        if link is not None:
            try:
                _replace_symlink(Path(link), self.path)
            except BaseException:
                self.close()  # the pty's descriptors are not leaked by a bad --link
                raise
            self.link = Path(link)

    # ------------------------------------------------------------------ BoardServer
    def board_time(self) -> float:
        with self.lock:
            return self.board.now

    def _release(self) -> None:
        """Close the pty and remove the symlink."""
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        if self.link is not None:
            with contextlib.suppress(OSError):
                if self.link.is_symlink() and os.readlink(self.link) == self.path:
                    self.link.unlink()

    # ------------------------------------------------------------------ the loop
    def serve(self, duration: float | None = None) -> None:
        """Run until :meth:`stop` (or for ``duration`` seconds of board time)."""
        board = self.board
        clock = board.clock
        end = None if duration is None else clock.now() + duration
        while not self.stopping():
            master = self._master
            if master is None:
                return
            with self.lock:
                now = clock.now()
                board.step(now)
                self.note_state(now, board.state)
                self._queue(board.take_output())
                if end is not None and now >= end:
                    return  # the board has run to the end of the duration
                wait = board.next_deadline() - clock.now()
            wait = min(max(wait, 0.0), _MAX_WAIT_S)
            if end is not None:
                wait = min(wait, max(end - clock.now(), 0.0))
            self.stats.loops += 1
            if self.link is not None and time.monotonic() >= self._next_link_check:
                self._keep_link(self.link)
            if self._host_absent:
                self._poll_absent_host(master, wait)
                continue
            looked = clock.now()  # the host is judged silent as of the look's start (HostPresence.tick)
            try:
                readable, writable, _ = select.select([master], [master] if self._out else [], [], wait)
            except (OSError, ValueError):
                return  # closed under us by close()
            if readable:
                self._read(master)
            else:
                with self.lock:
                    self.presence.tick(looked)
            if writable and self._out:
                self._write(master)

    def _keep_link(self, link: Path) -> None:
        """The symlink is what hosts open (``hil run --port LINK``): one that went while the board serves
        is made again (logged, counted in :attr:`link_remade`) — the board was left serving behind a path
        that no longer existed, and a host reconnecting through it never found it. A link that another
        server has since pointed at its own pty is that server's now, left alone (said once); a real file
        put there is never replaced (:func:`_replace_symlink`)."""
        self._next_link_check = time.monotonic() + LINK_CHECK_S
        try:
            target = os.readlink(link)
        except FileNotFoundError:
            target = None
        except OSError:  # a file or folder, not a link: someone else's, never replaced
            target = "a file that is not a symlink"
        if target == self.path:
            return
        if target is not None:
            if not self._link_taken_said:
                self._link_taken_said = True
                logger.warning("%s no longer points at %s (now: %s); left as it is", link, self.path, target)
            return
        try:
            _replace_symlink(link, self.path)
        except LinkError as exc:
            if not self._link_taken_said:
                self._link_taken_said = True
                logger.warning("%s was removed and cannot be made again: %s", link, exc)
            return
        self.link_remade += 1
        self._link_taken_said = False
        logger.warning("%s was removed while serving; it points at %s again", link, self.path)

    def _read(self, master: int) -> None:
        try:
            data = os.read(master, 65536)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                self._host_left()
                return
            raise
        if not data:
            self._host_left()
            return
        self._take_in(data)

    def _take_in(self, data: bytes) -> None:
        self.stats.bytes_in += len(data)
        self.stats.frames_in += self._frames_in.feed(data)
        with self.lock:
            self.board.feed(data)  # runs the board to its clock's now: the bytes are heard then, not before
            self.presence.heard(self.board.now)  # (a stall's waiting bytes: the host never left; can_server)
            self.note_state(self.board.now, self.board.state)

    def _write(self, master: int) -> None:
        try:
            n = os.write(master, self._out)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                self._host_left()
                return
            raise
        self.stats.bytes_out += n
        self.stats.frames_out += self._frames_out.feed(self._out[:n])
        del self._out[:n]

    def _queue(self, data: bytes) -> None:
        if self._host_absent:
            self.stats.dropped_out += len(data)
            return
        self._out += data
        if len(self._out) > _OUT_LIMIT:
            excess = len(self._out) - _OUT_LIMIT
            self.stats.dropped_out += excess
            del self._out[:excess]

    def _host_left(self) -> None:
        if not self._host_absent:
            logger.info("host closed %s; waiting for it to come back", self.path)
        self.presence.left()
        self._host_absent = True
        self.stats.dropped_out += len(self._out)
        self._out.clear()

    def _poll_absent_host(self, master: int, wait: float) -> None:
        """No host on the slave: master reads EIO until one opens it again. Sleep, then probe."""
        time.sleep(min(wait, _ABSENT_POLL_S))
        try:
            data = os.read(master, 65536)
        except BlockingIOError:
            self._host_absent = False  # a host has the slave open and is quiet
            logger.info("host is back on %s", self.path)
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                return
            raise
        if data:
            self._host_absent = False
            logger.info("host is back on %s", self.path)
            self._take_in(data)


def _replace_symlink(link: Path, target: str) -> None:
    """Point ``link`` at ``target`` atomically (rename over an old link); refuse to replace a real file."""
    if link.exists() and not link.is_symlink():
        raise LinkError(f"{link} exists and is not a symlink; refusing to replace it")
    tmp = link.with_name(f".{link.name}.{os.getpid()}.tmp")
    try:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        os.symlink(target, tmp)
        os.replace(tmp, link)
    except OSError as exc:
        raise LinkError(f"cannot make the link {link} -> {target}: {exc.strerror}") from exc
