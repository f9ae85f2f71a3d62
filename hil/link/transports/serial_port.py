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

import serial

from protocol.errors import LinkError, PortBusy, TransportError

from .base import Transport
from .port_holder import find_holder

DEFAULT_BAUDRATE = 115200
DRAIN_BYTES = 1 << 18
"""The most one read takes: everything waiting, up to this (a pty holds a few tens of KiB). A read takes
all that waited, so the next one holds only what came after it (:mod:`hil.link.board.made_at` dates a
read that came late by the board's clock, and one that came promptly by its receive time)."""


class SerialTransport(Transport):
    """A pyserial port. ``url`` is a device path or any pyserial URL; ``baudrate`` is ignored by ptys
    and sockets but matters on a real board's USB-serial adapter."""

    scheme = "serial"

    def __init__(self, url: str, baudrate: int = DEFAULT_BAUDRATE) -> None:
        super().__init__(url)
        self.baudrate = baudrate
        self._port: serial.SerialBase | None = None

    def _open_impl(self) -> None:
        port: serial.SerialBase | None = None
        try:
            port = serial.serial_for_url(
                self.url,
                baudrate=self.baudrate,
                timeout=0.05,
                write_timeout=2.0,
                exclusive=True,
                do_not_open=True,  # so a refused lock still tells which device it was (port.port)
            )
            port.open()
            self._port = port
        except serial.SerialException as exc:
            if exc.errno == errno.EWOULDBLOCK and port is not None and port.port:
                raise self._busy(str(port.port)) from exc
            raise TransportError(f"{self.url}: {exc}") from exc
        except (ValueError, KeyError) as exc:
            # pyserial's URL handlers raise ValueError for bad options; loop:// raises KeyError
            # (a format-string bug in its own error message), so both mean "bad URL options".
            raise TransportError(f"{self.url}: bad URL or options ({exc!r})") from exc

    def _busy(self, device: str) -> PortBusy:
        """The refusal of a port another process has locked, naming that process when it can be found."""
        real = os.path.realpath(device)
        where = self.url if real == self.url else f"{self.url} ({real})"
        holder = find_holder(real)
        return PortBusy(where) if holder is None else PortBusy(where, *holder)

    def _read(self, timeout: float | None) -> bytes:
        port = self._port
        assert port is not None
        try:
            if port.timeout != timeout:
                port.timeout = timeout
            first = port.read(1)
            if not first:
                return b""
            out = bytearray(first)
            while len(out) < DRAIN_BYTES:  # a pty reports at most 4095 waiting at a time: all of it
                waiting = port.in_waiting
                if not waiting:
                    break
                out += port.read(min(waiting, DRAIN_BYTES - len(out)))
            return bytes(out)
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"{self.url}: read failed (port vanished?): {exc}") from exc

    def _write(self, data: bytes) -> None:
        port = self._port
        assert port is not None
        try:
            port.write(data)
        except serial.SerialTimeoutException as exc:
            raise LinkError(f"{self.url}: write timed out (far side not reading?)") from exc
        except (serial.SerialException, OSError) as exc:
            raise LinkError(f"{self.url}: write failed (port vanished?): {exc}") from exc

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass  # closing a vanished port: nothing left to release
