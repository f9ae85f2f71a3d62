"""An HTTP receiving end that a peer on the network cannot exhaust: how the host's two servers — the phone
push receiver (:mod:`.phone_push`) and the ground station (:mod:`hil.gcs.server`) — read requests and
hold connections. One guard for both, so both pass the same hostile-peer tests.

Anything that can reach a server's port can connect. So, whatever a peer sends (:class:`HttpLimits`):

* a request body is at most ``max_body`` bytes, whatever the headers say (:func:`read_body`):
  ``Content-Length`` must be one plain decimal number (``-1``, ``abc``, ``+5``, ``1e3`` and two
  different values are refused 400; more than the limit is refused 413 before a byte of the body is
  read); ``Transfer-Encoding: chunked`` is decoded under the same cap, with bounded chunk-size lines
  and trailers; a POST with neither is refused 411; any other transfer coding 501;
* each request has ``timeout_s`` from the moment the server starts waiting for it to its last byte
  (:class:`DeadlineReader`): an idle connection and a peer dripping a byte a second (slowloris) are
  both closed, and reported (``timeout``); an answer the peer does not read within ``timeout_s`` ends
  the connection too;
* at most ``max_connections`` connections are served at once (:class:`GuardedHTTPServer`), each by a
  thread. A connection still *waiting* — for its request, or for the rest of its body — holds its slot
  only until a new connection needs it: then the one that has waited longest is closed (``evicted``),
  so idle or dripping sockets cannot lock the others out, while a request being answered or a stream
  being served is never cut. When every slot is busy (or ``max_connections`` evicted connections are
  still winding down), a new connection is closed unanswered (``connections``). Threads: at most
  ``2 * max_connections``, whatever a peer opens;
* a connection that ends is first drained of what the peer still sends, for at most ``linger_s`` and
  :data:`LINGER_BYTES` (a "lingering close"): closing a socket with unread input sends a reset, which
  can destroy the answer (a 413 before the body, a 401) before the peer reads it;
* nothing is printed: every turned-away request and connection is reported to the server's
  ``on_turned_away(reason, peer, detail)`` (each server counts and logs them its own way), a handler's
  exception included (``error``), and the server carries on. A peer that resets its connection before
  a byte of its next request has left, as one that closes it has: a phone whose app was killed, a
  client that closed with its last answer unread (the kernel then sends a reset). No request is lost,
  so nothing is reported; a reset in the middle of a request is (``error``).

:func:`read_body` needs only a readable binary file, so it is tested and fuzzed on ``io.BytesIO``.
"""

from __future__ import annotations

import contextlib
import io
import logging
import re
import socket
import sys
import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from email.message import Message
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any, Protocol

from protocol.errors import InputFormatError

logger = logging.getLogger(__name__)

MAX_LINE = 1024  # bytes: a chunk-size line or a trailer line longer than this is refused
MAX_TRAILERS = 32  # trailer lines after the last chunk
LINGER_BYTES = 1024 * 1024  # at most this much of what a peer still sends is read and dropped at the close
BACKLOG = 128  # connections the kernel holds until the server accepts them (socketserver's default: 5)
_DECIMAL = re.compile(r"[0-9]{1,19}")
_HEX = re.compile(r"[0-9a-fA-F]{1,16}")


@dataclass(frozen=True)
class HttpLimits:
    """What one server lets a peer hold: ``max_body`` bytes per request body, ``timeout_s`` seconds per
    request (from waiting for it to its last byte; also per answer written), ``max_connections`` served at
    once, ``linger_s`` seconds of draining at a connection's close."""

    max_body: int
    timeout_s: float
    max_connections: int
    linger_s: float = 1.0

    def __post_init__(self) -> None:
        if self.max_body < 0 or self.timeout_s <= 0 or self.max_connections < 1 or self.linger_s < 0:
            raise ValueError(f"impossible HTTP limits: {self}")


TurnedAway = Callable[[str, str, str], None]
"""``on_turned_away(reason, peer, detail)``: a request or connection the guard turned away — ``timeout``,
``evicted``, ``connections`` (the cap), ``error`` (a handler's exception), or what a handler refuses."""


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
    content = _content_coding(headers, source)  # refused before a byte of the body is read
    if codings:
        if codings != ["chunked"]:
            raise BodyError(501, f"transfer coding {', '.join(codings)!r} is not supported", source)
        body = _read_chunked(rfile, limit, source)
    else:
        length = content_length(headers, limit, source)
        if length is None:
            raise BodyError(411, "a POST needs a Content-Length or chunked transfer coding", source)
        body = rfile.read(length)
        if len(body) != length:
            raise BodyError(
                400, f"the connection ended {length - len(body)} bytes before the body did", source
            )
    return body if content is None else _decompressed(body, content, limit, source)


_CONTENT_CODINGS = {"gzip": 16 + zlib.MAX_WBITS, "x-gzip": 16 + zlib.MAX_WBITS, "deflate": zlib.MAX_WBITS}
"""The content codings a body may come in (``Content-Encoding``), as zlib's window bits."""


def _content_coding(headers: Message, source: str) -> str | None:
    """The body's ``Content-Encoding`` (None: identity); one the server cannot undo is a 415."""
    codings = [c.strip().lower() for v in headers.get_all("Content-Encoding", []) for c in v.split(",")]
    codings = [c for c in codings if c and c != "identity"]
    if not codings:
        return None
    if len(codings) > 1 or codings[0] not in _CONTENT_CODINGS:
        raise BodyError(
            415, f"content coding {', '.join(codings)!r} is not supported (gzip, deflate)", source
        )
    return codings[0]


MAX_MEMBERS = 64
"""gzip members (RFC 1952 §2.2: a gzip body is a series of members) undone in one body; more is a 400. A
client compresses a body as one member, a few if it streams; 64 bounds the work a body of empty members
asks for (18 bytes each: 4 MiB would be 230 000 decompressors)."""


def _decompressed(body: bytes, coding: str, limit: int, source: str) -> bytes:
    """A gzip or deflate ``body`` undone, at most ``limit`` bytes of it (a small body that unpacks to
    gigabytes is a 413, not the memory it asks for). Every gzip member is undone (at most
    :data:`MAX_MEMBERS`), each whole: a stream cut short (its CRC-32 and length trailer missing: zlib
    checks them only at a member's end) or bytes after the last member that are not one are a 400 — a
    body is taken whole or not at all (before: a second member was "not JSON", a member cut short or
    followed by garbage was taken)."""
    wbits = _CONTENT_CODINGS[coding]
    out = bytearray()
    rest = body
    for _ in range(MAX_MEMBERS):
        unpacker = zlib.decompressobj(wbits=wbits)
        try:
            out += unpacker.decompress(rest, limit + 1 - len(out))  # >= 1: 0 would mean no limit
        except zlib.error as exc:
            raise BodyError(400, f"not {coding} data ({exc})", source) from None
        if len(out) > limit or unpacker.unconsumed_tail:
            raise BodyError(413, f"a {coding} body that unpacks to more than {limit} bytes", source)
        if not unpacker.eof:
            raise BodyError(400, f"a {coding} body cut short (its stream does not end)", source)
        rest = unpacker.unused_data
        if not rest:
            return bytes(out)
        if coding == "deflate" or not rest.startswith(b"\x1f\x8b"):
            raise BodyError(400, f"{len(rest)} bytes after the end of the {coding} data", source)
    raise BodyError(400, f"a gzip body of more than {MAX_MEMBERS} members", source)


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


class GuardedHTTPServer(ThreadingHTTPServer):
    """A threading HTTP server that serves at most ``limits.max_connections`` connections at once, evicts
    the longest-waiting idle one when a new connection needs its slot, and reports every connection it
    turns away, and every handler's exception, to ``on_turned_away`` (nothing printed). Its handler must
    derive from :class:`GuardedHandler`. Handler threads are daemons; :meth:`server_close` does not wait
    for them (:meth:`close_connections` ends them)."""

    daemon_threads = True
    block_on_close = False
    request_queue_size = BACKLOG

    def __init__(
        self,
        address: tuple[str, int],
        handler: type[GuardedHandler],
        limits: HttpLimits,
        on_turned_away: TurnedAway,
    ) -> None:
        self.limits = limits
        self.on_turned_away = on_turned_away
        self.active = 0  # connections with a thread (evicted ones winding down included)
        self.refused = 0
        self.evicted = 0
        self._slots = threading.Lock()
        self._open: set[socket.socket] = set()
        self._waiting: dict[socket.socket, str] = {}  # waiting for (the rest of) a request: oldest first
        self._leaving: set[socket.socket] = set()  # evicted, their thread not yet ended
        super().__init__(address, handler)

    # ------------------------------------------------------------------ slots (the accept thread)
    def verify_request(self, request: Any, client_address: Any) -> bool:
        peer = str(client_address[0])
        evicted: tuple[socket.socket, str] | None = None
        with self._slots:
            live = self.active - len(self._leaving)
            cap = self.limits.max_connections
            if live >= cap and self._waiting and len(self._leaving) < cap:
                sock, who = next(iter(self._waiting.items()))  # the one that has waited longest
                del self._waiting[sock]
                self._leaving.add(sock)
                self.evicted += 1
                evicted = (sock, who)
                live -= 1
            admitted = live < cap
            if admitted:
                self.active += 1
                self._open.add(request)
                self._waiting[request] = peer
            else:
                self.refused += 1
                refused, active = self.refused, self.active
        if evicted is not None:
            with contextlib.suppress(OSError):  # its thread's read returns at once: the thread ends
                evicted[0].shutdown(socket.SHUT_RDWR)
            self.on_turned_away("evicted", evicted[1], "closed while waiting: its slot was needed")
        if admitted:
            return True
        if refused == 1 or refused % 100 == 0:
            logger.warning("%d connection(s) refused so far: %d open", refused, active)
        self.on_turned_away("connections", peer, f"{self.limits.max_connections} connections open")
        return False

    def process_request(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request(request, client_address)
        except BaseException:  # the thread did not start: its slot is free again
            self._release(request)
            raise

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self._release(request)

    def _release(self, request: socket.socket) -> None:
        with self._slots:
            self.active -= 1
            self._open.discard(request)
            self._waiting.pop(request, None)
            self._leaving.discard(request)

    # ------------------------------------------------------------------ what handlers say
    def mark(self, request: socket.socket, peer: str, waiting: bool) -> None:
        """``request`` is waiting for (the rest of) a request — evictable, the longest waiting first — or
        busy answering one (never evicted)."""
        with self._slots:
            if request in self._leaving or request not in self._open:
                return
            self._waiting.pop(request, None)
            if waiting:
                self._waiting[request] = peer

    def was_evicted(self, request: socket.socket) -> bool:
        with self._slots:
            return request in self._leaving

    def close_connections(self) -> None:
        """End every open connection (their threads then end): for a server that is closing."""
        with self._slots:
            sockets = list(self._open)
        for sock in sockets:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)

    def handle_error(self, request: Any, client_address: Any) -> None:
        """socketserver prints a traceback here; a handler's exception is reported instead (an evicted
        connection's failing write is no news)."""
        exc = sys.exc_info()[1]
        logger.debug("connection from %s failed", client_address[0], exc_info=True)
        if not self.was_evicted(request):
            detail = f"{type(exc).__name__}: {exc}"[:300]
            self.on_turned_away("error", str(client_address[0]), detail)


class GuardedHandler(BaseHTTPRequestHandler):
    """The request handler half of the guard: every request read under a :class:`DeadlineReader`, the
    connection marked waiting (evictable) until its request — body included, when read through
    :meth:`read_body` — is in, answers written under a deadline, http.server's own refusals (a malformed
    request line, an unsupported method, headers too long) reported, a lingering close. Subclasses write
    ``do_GET``/``do_POST`` as usual."""

    server: GuardedHTTPServer

    def setup(self) -> None:
        super().setup()
        limits = self.server.limits
        self.rfile.close()  # makefile()'s reader: replaced by one with a deadline per request
        self._reader = DeadlineReader(self.connection, limits.timeout_s, self._timed_out)
        self._buffered = io.BufferedReader(self._reader)
        self.rfile = self._buffered
        self._peer = str(self.client_address[0])

    def handle_one_request(self) -> None:
        self._answered = False
        self._reader.start()  # the next request, from waiting for it to its last byte: timeout_s
        self.server.mark(self.connection, self._peer, waiting=True)
        try:
            self._buffered.peek(1)  # a pipelined request's bytes, if buffered; else waits for the first byte
        except TimeoutError:
            self.close_connection = True  # reported by the reader's on_timeout
            return
        except ConnectionError:
            logger.debug("%s reset its connection between requests", self._peer)
            self.close_connection = True
            return
        super().handle_one_request()

    def parse_request(self) -> bool:
        ok = super().parse_request()
        if ok:  # the head is in: answering it is never cut by an eviction
            self.server.mark(self.connection, self._peer, waiting=False)
        return ok

    def read_body(self, source: str, limit: int | None = None) -> bytes:
        """This request's body (:func:`read_body`, at most ``limit`` or the server's ``max_body``; errors
        name ``source``); the connection is evictable while it trickles in. Raises :class:`BodyError`."""
        cap = self.server.limits.max_body if limit is None else limit
        self.server.mark(self.connection, self._peer, waiting=True)
        try:
            return read_body(self.headers, self.rfile, cap, source)
        finally:
            self.server.mark(self.connection, self._peer, waiting=False)

    def deadline_for_answer(self, seconds: float | None = None) -> None:
        """A peer that does not read its answer cannot hold the thread: writes wait at most ``seconds``
        (default the request deadline)."""
        self.connection.settimeout(self.server.limits.timeout_s if seconds is None else seconds)

    def send_response(self, code: int, message: str | None = None) -> None:
        self._answered = True
        super().send_response(code, message)

    def _timed_out(self) -> None:
        if not self.server.was_evicted(self.connection):
            detail = f"no complete request within {self._reader.timeout_s} s"
            self.server.on_turned_away("timeout", self._peer, detail)

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """http.server's own refusals (400 bad request line, 414, 431, 501 unsupported method) are
        reported like the handlers' ones, and answered under the write deadline."""
        self.server.on_turned_away("request", self._peer, f"{code} {message or ''}".strip()[:200])
        self.close_connection = True
        self.deadline_for_answer()
        with contextlib.suppress(OSError):
            super().send_error(code, message, explain)

    def finish(self) -> None:
        with contextlib.suppress(OSError):
            super().finish()
        self._linger()

    def _linger(self) -> None:
        """After an answer, send our FIN, then read and drop what the peer still sends until it closes,
        for at most ``linger_s`` and :data:`LINGER_BYTES`: so the answer is not destroyed by a reset. (A
        connection closed without an answer — timed out, evicted — has nothing to protect.)"""
        sock = self.connection
        if not getattr(self, "_answered", False) or self.server.was_evicted(sock):
            return
        self.server.mark(sock, self._peer, waiting=True)  # a slot needed meanwhile ends the lingering
        end = time.monotonic() + self.server.limits.linger_s
        left = LINGER_BYTES
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_WR)
            while left > 0:
                remaining = end - time.monotonic()
                if remaining <= 0:
                    break
                sock.settimeout(remaining)
                data = sock.recv(min(left, 65536))
                if not data:
                    break
                left -= len(data)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (http.server's naming)
        logger.debug("%s %s", self._peer if hasattr(self, "_peer") else "?", format % args)
