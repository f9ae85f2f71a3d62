"""An HTTP/1.1 receiving end that a peer on the network cannot exhaust: how the phone-push server reads
request bodies and holds connections.

A phone on the Wi-Fi pushes its batches to the host; anything else on that network can connect too. So,
whatever a peer sends:

* a request body is at most ``limit`` bytes, whatever the headers say (:func:`read_body`):
  ``Content-Length`` must be one plain decimal number (``-1``, ``abc``, ``+5``, ``1e3`` and two
  different values are refused 400; more than ``limit`` is refused 413 before a byte of the body is
  read); ``Transfer-Encoding: chunked`` is decoded under the same cap, with bounded chunk-size lines
  and trailers; a POST with neither is refused 411; any other transfer coding 501;
* each request has ``timeout_s`` from the moment the server starts waiting for it to its last byte
  (:class:`DeadlineReader`): an idle keep-alive connection and a peer dripping a byte a second are
  both closed, and counted;
* at most ``max_connections`` connections are served at once (:class:`BoundedHTTPServer`); the ones
  beyond are closed at once, and counted;
* nothing is printed: a connection's error is counted and logged, and the server carries on.

:func:`read_body` needs only a readable binary file, so it is tested and fuzzed on ``io.BytesIO``.
"""

from __future__ import annotations

import io
import logging
import re
import socket
import sys
import threading
import time
from collections.abc import Callable
from email.message import Message
from http.server import ThreadingHTTPServer
from typing import Any, Protocol

from protocol.errors import InputFormatError

logger = logging.getLogger(__name__)

MAX_LINE = 1024  # bytes: a chunk-size line or a trailer line longer than this is refused
MAX_TRAILERS = 32  # trailer lines after the last chunk
_DECIMAL = re.compile(r"[0-9]{1,19}")
_HEX = re.compile(r"[0-9a-fA-F]{1,16}")


class ByteReader(Protocol):
    """What :func:`read_body` reads from: a connection's buffered reader, or ``io.BytesIO``."""

    def read(self, size: int = -1, /) -> bytes: ...

    def readline(self, size: int = -1, /) -> bytes: ...


class BodyError(InputFormatError):
    """A request body that is refused; ``status`` is the HTTP status to answer it with."""

    def __init__(self, status: int, detail: str, source: str = "") -> None:
        super().__init__(detail, source)
        self.status = status


def read_body(headers: Message, rfile: ByteReader, limit: int, source: str = "http") -> bytes:
    """The body of a request with ``headers``, read from ``rfile``: at most ``limit`` bytes, whatever
    the headers claim. Raises :class:`BodyError` (with the status to answer) naming ``source``; a peer
    that stops sending raises whatever ``rfile`` raises (a timeout, a closed connection)."""
    codings = [c.strip().lower() for v in headers.get_all("Transfer-Encoding", []) for c in v.split(",")]
    codings = [c for c in codings if c]
    if codings:
        if codings != ["chunked"]:
            raise BodyError(501, f"transfer coding {', '.join(codings)!r} is not supported", source)
        return _read_chunked(rfile, limit, source)
    length = content_length(headers, limit, source)
    if length is None:
        raise BodyError(411, "a POST needs a Content-Length or chunked transfer coding", source)
    body = rfile.read(length)
    if len(body) != length:
        raise BodyError(400, f"the connection ended {length - len(body)} bytes before the body did", source)
    return body


def content_length(headers: Message, limit: int, source: str = "http") -> int | None:
    """The request's ``Content-Length`` (None if absent), checked: one plain decimal number, every copy
    of the header the same, at most ``limit``."""
    values = {v.strip() for v in headers.get_all("Content-Length", [])}
    if not values:
        return None
    if len(values) > 1:
        raise BodyError(400, f"contradicting Content-Length headers {sorted(values)}", source)
    (text,) = values
    if not _DECIMAL.fullmatch(text):
        raise BodyError(400, f"Content-Length {text[:40]!r} is not a byte count", source)
    length = int(text)
    if length > limit:
        raise BodyError(413, f"a body of {length} bytes is larger than {limit}", source)
    return length


def _read_chunked(rfile: ByteReader, limit: int, source: str) -> bytes:
    body = bytearray()
    while True:
        size_text = _line(rfile, source).split(b";", 1)[0].strip().decode("ascii", "replace")
        if not _HEX.fullmatch(size_text):
            raise BodyError(400, f"chunk size {size_text[:40]!r} is not a hex number", source)
        size = int(size_text, 16)
        if len(body) + size > limit:
            raise BodyError(413, f"a chunked body of more than {limit} bytes", source)
        if size == 0:
            break
        chunk = rfile.read(size)
        if len(chunk) != size or _line(rfile, source) != b"":
            raise BodyError(400, "a chunk that does not end where its size says", source)
        body += chunk
    for _ in range(MAX_TRAILERS):
        if _line(rfile, source) == b"":
            return bytes(body)
    raise BodyError(400, f"more than {MAX_TRAILERS} trailer lines", source)


def _line(rfile: ByteReader, source: str) -> bytes:
    """One CRLF-terminated line without its ending; refused if longer than :data:`MAX_LINE` or cut."""
    line = rfile.readline(MAX_LINE + 1)
    if not line.endswith(b"\n"):
        raise BodyError(400, "a chunk-size or trailer line that is too long or cut off", source)
    return line.rstrip(b"\r\n")


class DeadlineReader(io.RawIOBase):
    """The read side of a connection with a deadline per request: :meth:`start` sets it ``timeout_s``
    ahead; every read after that waits at most until then and raises :class:`TimeoutError` once it has
    passed, however the peer trickles its bytes (``on_timeout`` hears of it first). ``clock`` is
    monotonic seconds (injected for tests)."""

    def __init__(
        self,
        sock: socket.socket,
        timeout_s: float,
        on_timeout: Callable[[], None] = lambda: None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__()
        self._sock = sock
        self.timeout_s = timeout_s
        self._on_timeout = on_timeout
        self._clock = clock
        self._deadline = clock() + timeout_s

    def start(self) -> None:
        self._deadline = self._clock() + self.timeout_s

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        remaining = self._deadline - self._clock()
        try:
            if remaining <= 0:
                raise TimeoutError(f"no complete request within {self.timeout_s} s")
            self._sock.settimeout(remaining)
            return self._sock.recv_into(buffer)
        except TimeoutError:
            self._on_timeout()
            raise


class BoundedHTTPServer(ThreadingHTTPServer):
    """A threading HTTP server serving at most ``max_connections`` connections at once; the ones beyond
    are closed unanswered (``on_refused()`` hears of each). ``on_error(reason)`` hears of every connection
    that ended in an exception (nothing is printed). Handler threads are daemons."""

    daemon_threads = True

    def __init__(
        self,
        address: tuple[str, int],
        handler: type,
        max_connections: int,
        on_refused: Callable[[], None],
        on_error: Callable[[str], None],
    ) -> None:
        self.max_connections = max_connections
        self.active = 0
        self.refused = 0
        self._on_refused = on_refused
        self._on_error = on_error
        self._slots = threading.Lock()
        super().__init__(address, handler)

    def verify_request(self, request: Any, client_address: Any) -> bool:
        with self._slots:
            if self.active < self.max_connections:
                self.active += 1
                return True
            self.refused += 1
            refused = self.refused
        self._on_refused()
        if refused == 1 or refused % 100 == 0:
            logger.warning("%d connection(s) refused so far: %d open", refused, self.max_connections)
        return False

    def process_request(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request(request, client_address)
        except BaseException:  # the thread did not start: its slot is free again
            self._release()
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._release()

    def _release(self) -> None:
        with self._slots:
            self.active -= 1

    def handle_error(self, request: Any, client_address: Any) -> None:
        """socketserver prints a traceback here; a peer's bad request is counted and logged instead."""
        exc = sys.exc_info()[1]
        self._on_error(f"connection from {client_address[0]} failed: {type(exc).__name__}: {exc}"[:300])
        logger.debug("phone push connection from %s failed", client_address[0], exc_info=True)
