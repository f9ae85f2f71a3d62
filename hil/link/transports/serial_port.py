"""Serial devices and pyserial URLs: ``/dev/pts/N``, ``/dev/ttyACM0``, ``socket://host:port``,
``loop://``, ``spy://PORT?file=...`` (hexdump of all traffic), ``rfc2217://``.

Pty pitfalls handled (see pyserial): reads always have a deadline; DTR/RTS are not touched on a pty;
a far side that closes makes ``read()`` raise "device reports readiness to read but returned no
data" or EIO — both become :class:`LinkError` so the board client can reconnect.

Every port is opened exclusively (pyserial's ``exclusive=True``: ``flock(LOCK_EX | LOCK_NB)`` on the
device, for device paths and the URL handlers that open one, ``spy://`` and ``hwgrep://``; the socket and
loop handlers ignore it). Two hosts on one board would each handshake, and a handshake leaves the board
DISARMED under the other host; the lock refuses the second host instead, as :class:`PortBusy` naming the
process that holds the port. ``firmware-sim`` keeps the pty's slave open without a lock, so it never
stands in the host's way.
"""

from __future__ import annotations

import errno
import os
import termios
from dataclasses import dataclass
from typing import Any

import serial

from protocol.errors import LinkError, PortBusy, TransportError, TransportRefused

from .base import Transport
from .port_holder import find_holder

DEFAULT_BAUDRATE = 115200
DRAIN_BYTES = 1 << 18
"""The most one read takes: everything waiting, up to this (a pty holds a few tens of KiB). A read takes
all that waited, so the next one holds only what came after it (:mod:`hil.link.board.made_at` dates a
read that came late by the board's clock, and one that came promptly by its receive time)."""


def _waiting_is_a_flag(port: serial.SerialBase) -> bool:
    """Whether ``port.in_waiting`` says only *whether* bytes wait, not how many: pyserial's ``socket://``
    answers ``len(select(...)[0])``, 0 or 1, so a drain by it read one byte a call — 1 MiB from a fast
    far side cost 7 s of CPU in 4 reads, the session fed nothing meanwhile. Such a port is drained by one
    read of timeout 0 (its socket's ``recv`` of what has come), not by the count."""
    return type(port).__module__.endswith("protocol_socket")


def _is_spy(port: serial.SerialBase) -> bool:
    """Whether ``port`` is pyserial's ``spy://`` wrapper. Its handler opens the dump's ``file=`` anew (mode
    ``"w"``: emptied) each time such a port is made, so one made for each connection emptied the dump of
    every earlier one at the link's first reconnect — the traffic up to the loss, which is what a spy is
    for. The transport makes it once and opens it again on each reconnect, the dump going on."""
    return type(port).__module__.endswith("protocol_spy")


class _BinaryLayer:
    """A text stream's binary layer (its ``buffer``; the bytes as Latin-1 characters for a stream that has
    none), taking bytes and the ``str`` escapes of ``color`` alike: what pyserial's spy ``raw`` formatter
    writes."""

    def __init__(self, text: Any) -> None:
        self.text = text

    def write(self, data: bytes | str) -> None:
        raw = data.encode() if isinstance(data, str) else bytes(data)
        buffer = getattr(self.text, "buffer", None)
        if buffer is None:
            self.text.write(raw.decode("latin-1"))
            return
        self.text.flush()  # what the text layer holds goes first
        buffer.write(raw)

    def flush(self) -> None:
        self.text.flush()
        buffer = getattr(self.text, "buffer", None)
        if buffer is not None:
            buffer.flush()


def _spy_takes_bytes(port: serial.SerialBase) -> None:
    """Let a spy's ``raw`` formatter write what it sees. pyserial's ``FormatRaw`` writes the port's bytes
    into its output, which the handler opens as text (``file=``, or ``sys.stderr``): the first write of a
    ``spy://PORT?raw`` was a ``TypeError`` out of ``write()``, ``hil run`` ending on a traceback. It is
    given the output's binary layer instead (:class:`_BinaryLayer`); the hexdump writes text, as it is."""
    formatter: Any = getattr(port, "formatter", None)
    if type(formatter).__name__ == "FormatRaw" and not isinstance(formatter.output, _BinaryLayer):
        formatter.output = _BinaryLayer(formatter.output)


def _no_serial_port(exc: serial.SerialException) -> bool:
    """Whether pyserial's refusal says the path is there and is no serial port — a folder (EISDIR), a
    regular file, a FIFO or a device that is no terminal (ENOTTY: pyserial's termios set-up refused,
    without an errno of its own, the ``termios.error`` its context) — or can never name one: a name longer
    than the system takes (ENAMETOOLONG), a loop of symbolic links (ELOOP). Trying again for the run's
    outage bound cannot mend those (a port not there yet, or busy for a moment, can be)."""
    codes = {exc.errno}
    context = exc.__context__
    if isinstance(context, termios.error) and context.args:
        codes.add(context.args[0])
    if isinstance(context, OSError):
        codes.add(context.errno)
    return bool(codes & {errno.EISDIR, errno.ENOTTY, errno.ENAMETOOLONG, errno.ELOOP})


def _url_fault(exc: BaseException) -> str | None:
    """What a pyserial URL handler found wrong with the URL itself, said plainly; None when ``exc`` is no
    such refusal (a connection refused, a name not resolved, a device not there yet: tried again).

    The handlers parse the URL inside ``open()`` and wrap what they raise: ``socket://`` raises a
    ``ValueError`` (a port out of 0..65535 or not a number, an unknown option, a malformed IPv6 host), then
    formats its message with a stray ``{...}``, so a ``KeyError('debug|info|warning|error')`` raised over it
    is what its ``SerialException`` quotes; an unknown ``logging`` level is a bare ``KeyError``. The
    deepest ``ValueError`` or ``KeyError`` in the chain (never an ``OSError``: a socket's errors are
    network faults) is the cause; seen only as a ``SerialException``, a ``socket://localhost:99999`` was
    tried again for the run's whole outage bound (15 s), the error quoting ``'debug|info|warning|error'``."""
    found: BaseException | None = None
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        seen.add(id(link))
        if isinstance(link, (ValueError, KeyError)) and not isinstance(link, OSError):
            found = link
        link = link.__cause__ or link.__context__
    if found is None:
        return None
    if isinstance(found, KeyError):
        return f"no such value {found.args[0]!r}" if found.args else "a value it does not know"
    return str(found) or type(found).__name__


class SerialTransport(Transport):
    """A pyserial port. ``url`` is a device path or any pyserial URL; ``baudrate`` is ignored by ptys
    and sockets but matters on a real board's USB-serial adapter."""

    scheme = "serial"

    def __init__(self, url: str, baudrate: int = DEFAULT_BAUDRATE) -> None:
        super().__init__(url)
        self.baudrate = baudrate
        self._port: serial.SerialBase | None = None
        self._link_at_open: _PtyLink | None = None  # the link to a pty last opened through, as it was
        self._pty_gone = False  # that pty went away since (its far side closed it, or it was seen gone)
        self._waiting_is_a_flag = False  # the open port's in_waiting says only whether (_waiting_is_a_flag)
        # a spy:// port, made once and opened again on each reconnect (_is_spy: its dump goes on)
        self._spy: serial.SerialBase | None = None

    def present(self) -> bool | None:
        """A device path (``/dev/ttyACM0``, a firmware-sim ``--link``): whether it leads to a device now (a
        link left dangling by a killed firmware-sim does not, nor one whose pty's number another program
        has since been given: :meth:`_reused`); a pyserial URL (``socket://``…): None."""
        if "://" in self.url:
            return None
        if self._reused():
            return False
        there = os.path.exists(self.url)
        if not there and self._link_at_open is not None:
            self._pty_gone = True
        return there

    def _reused(self) -> bool:
        """Whether the path is the link to a pty that went away, unchanged since, and leads to a pty again:
        that pty's number was given to another program (another board's firmware-sim, a terminal), not
        our board back — a firmware-sim started again makes its link anew. Opened, the Hello the client
        then sends would reach that program (another board: disarmed by it) and hold its port."""
        return (
            self._pty_gone
            and self._link_at_open is not None
            and _pty_link(self.url) == self._link_at_open
            and os.path.exists(self.url)
        )

    def _open_impl(self) -> None:
        if self._reused():
            assert self._link_at_open is not None
            raise TransportError(
                f"{self.url}: still the link to {self._link_at_open.target}, the pty of a board that went "
                "away, whose number another program now has; waiting for the link to be made anew (a "
                "firmware-sim started again makes it)"
            )
        port: serial.SerialBase | None = self._spy
        try:
            if port is None:
                port = self._made_port()
                if _is_spy(port):
                    _spy_takes_bytes(port)
                    self._spy = port
            port.open()
            self._port = port
            self._waiting_is_a_flag = _waiting_is_a_flag(port)
            self._link_at_open, self._pty_gone = _pty_link(self.url), False
        except serial.SerialException as exc:
            if exc.errno == errno.EWOULDBLOCK and port is not None and port.port:
                raise self._busy(str(port.port)) from exc
            if _no_serial_port(exc):
                raise TransportRefused(f"{self.url}: not a serial port ({exc})") from exc
            bad_url = _url_fault(exc)
            if bad_url is not None:  # a URL handler's refusal of the URL, wrapped by its open()
                raise TransportRefused(f"{self.url}: bad URL or options: {bad_url}") from exc
            raise TransportError(f"{self.url}: {exc}") from exc
        except (ValueError, KeyError) as exc:
            # pyserial's URL handlers raise ValueError for bad options; loop:// raises KeyError
            # (a format-string bug in its own error message), so both mean "bad URL options": no board,
            # however long it is tried
            raise TransportRefused(f"{self.url}: bad URL or options: {_url_fault(exc) or repr(exc)}") from exc

    def _made_port(self) -> serial.SerialBase:
        """The URL's port object, not opened yet (so a refused lock still tells which device it was,
        ``port.port``). Nothing of the device is touched here, so an ``OSError`` of its own is what a URL
        handler opened for itself — a ``spy://`` URL's ``file=`` in a folder that is not there, or not
        writable — which no retry mends: it was tried again for the run's whole outage bound (15 s)."""
        try:
            return serial.serial_for_url(
                self.url,
                baudrate=self.baudrate,
                timeout=0.05,
                write_timeout=2.0,
                exclusive=True,
                do_not_open=True,
            )
        except OSError as exc:
            if isinstance(exc, serial.SerialException):
                raise
            raise TransportRefused(f"{self.url}: bad URL or options: {exc}") from exc

    def _busy(self, device: str) -> PortBusy:
        """The refusal of a port another process has locked, naming that process when it can be found."""
        real = os.path.realpath(device)
        where = self.url if real == self.url else f"{self.url} ({real})"
        holder = find_holder(real)
        return PortBusy(where) if holder is None else PortBusy(where, *holder)

    def _read(self, timeout: float | None) -> bytes:
        port = self._port
        assert port is not None
        out = bytearray()
        try:
            if port.timeout != timeout:
                port.timeout = timeout
            out += port.read(1)
            if not out:
                return b""
            if self._waiting_is_a_flag:  # take what has come at once, up to the bound
                port.timeout = 0
                try:
                    out += port.read(DRAIN_BYTES - 1)
                finally:
                    port.timeout = timeout
                return bytes(out)
            while len(out) < DRAIN_BYTES:  # a pty reports at most 4095 waiting at a time: all of it
                waiting = port.in_waiting
                if not waiting:
                    break
                out += port.read(min(waiting, DRAIN_BYTES - len(out)))
            return bytes(out)
        except (serial.SerialException, OSError) as exc:
            # a pty fails a read once its far side closed (not when our own close came under the read)
            self._pty_gone = self._open and self._link_at_open is not None
            failure = LinkError(f"{self.url}: read failed (port vanished?): {exc}")
            failure.__cause__ = exc
            return self._hand_up_then_fail(out, failure)  # what came before the end is the far side's last

    def _write(self, data: bytes) -> None:
        port = self._port
        assert port is not None
        try:
            port.write(data)
        except serial.SerialTimeoutException as exc:
            raise LinkError(f"{self.url}: write timed out (far side not reading?)") from exc
        except (serial.SerialException, OSError) as exc:
            self._pty_gone = self._open and self._link_at_open is not None
            raise LinkError(f"{self.url}: write failed (port vanished?): {exc}") from exc

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass  # closing a vanished port: nothing left to release


@dataclass(frozen=True)
class _PtyLink:
    """A symbolic link to a pty (``/dev/pts/N``), as it was: its own inode and change time, its target."""

    inode: int
    changed_ns: int
    target: str


def _pty_link(path: str) -> _PtyLink | None:
    """``path`` as a :class:`_PtyLink` if it is a symbolic link to a pty (firmware-sim's ``--link``); None
    for anything else (a device node, a udev ``/dev/serial/by-id`` link to a tty, no such path)."""
    try:
        stat = os.lstat(path)
        target = os.readlink(path) if os.path.islink(path) else ""
    except OSError:
        return None
    if not target.startswith("/dev/pts/"):
        return None
    return _PtyLink(stat.st_ino, stat.st_ctime_ns, target)
