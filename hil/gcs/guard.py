"""What a client may hold of the ground station's tornado server, beyond what tornado's own settings bound
(docs/gcs.md, "Security"): the connection cap with eviction, the whole-request deadline, and a report for
every connection turned away.

Tornado bounds each phase of a request (``idle_connection_timeout`` for the head, ``body_timeout`` for the
body, ``max_header_size``, ``max_body_size``, ``max_buffer_size``: :func:`tornado_settings`) but closes
silently, has no cap on connections, and logs what it refuses through ``logging`` rather than telling the
application. :class:`ConnectionGuard` adds, on the server's IOLoop thread (no locks needed):

* at most ``max_connections`` open connections. A connection still *waiting* — for its request head, or
  for the rest of its body — holds its slot only until a new connection needs it: then the one that has
  waited longest is closed (``evicted``), so idle or dripping sockets cannot lock the others out; a
  request being answered or a stream being served is never cut. When every slot is busy, the newcomer is
  closed unanswered (``connections``);
* each connection has ``timeout_s`` from being accepted to its request's last byte (the request is
  complete when a handler starts on it, :meth:`ConnectionGuard.busy`); past that it is closed
  (``timeout``), so a client dripping a byte a second is cut off however each phase fares. An answer the
  client does not read within ``timeout_s`` of its end closes the connection too (not a rejection:
  counted in ``answers_abandoned``);
* what tornado refuses before a handler runs (a malformed request line or header: tornado answers a bare
  400; a request head over ``max_header_size``: closed) is reported as ``request`` through
  :class:`TornadoReports`, a filter on tornado's ``tornado.general`` logger that takes those records from
  a ground-station thread and does not let them through (nothing printed).

Every report goes to ``on_turned_away(reason, peer, detail)`` (the server counts it and logs it in the
run's events: :meth:`hil.gcs.server.GcsServer.turned_away`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from tornado.ioloop import IOLoop
from tornado.iostream import IOStream, UnsatisfiableReadError

from hil.link.sources.http_guard import LINGER_BYTES, HttpLimits

MAX_HEADER = 16 * 1024  # bytes: a request line with its headers; longer is closed (``request``)
READ_BUFFER = LINGER_BYTES  # bytes tornado may buffer from one connection (its ``max_buffer_size``)

TurnedAway = Callable[[str, str, str], None]


def tornado_settings(limits: HttpLimits) -> dict[str, Any]:
    """``tornado.httpserver.HTTPServer`` keyword arguments for ``limits``: tornado's own bound on each
    phase (head and body at most ``timeout_s`` each; :class:`ConnectionGuard`'s deadline covers the two
    together), heads of at most :data:`MAX_HEADER` bytes, bodies of at most ``LINGER_BYTES`` (a command
    handler refuses more than ``max_body`` itself, answering 413 rather than tornado's bare 400, and the
    rest up to this is read and dropped so the refusal is not lost to a reset), one request per
    connection (``no_keep_alive``: the page makes a handful of requests; an idle keep-alive socket would
    only hold a slot)."""
    return {
        "no_keep_alive": True,
        "idle_connection_timeout": limits.timeout_s,
        "body_timeout": limits.timeout_s,
        "max_header_size": MAX_HEADER,
        "max_body_size": max(limits.max_body, LINGER_BYTES),
        "max_buffer_size": max(READ_BUFFER, MAX_HEADER * 2),
    }


@dataclass
class _Connection:
    stream: IOStream
    address: Any
    peer: str
    accepted: float  # IOLoop time (s)
    busy: bool = False
    closed_by_guard: bool = False
    timer: object | None = None


@dataclass
class GuardCounters:
    open: int = 0
    refused: int = 0  # closed unanswered: every slot busy
    evicted: int = 0
    timed_out: int = 0
    answers_abandoned: int = 0  # an answer the client did not read within timeout_s
    accepted: int = 0


class ConnectionGuard:
    """The connections of one server (see the module docstring). Every method runs on ``loop``'s thread."""

    def __init__(self, loop: IOLoop, limits: HttpLimits, on_turned_away: TurnedAway) -> None:
        self.loop = loop
        self.limits = limits
        self.on_turned_away = on_turned_away
        self.counters = GuardCounters()
        self._connections: dict[int, _Connection] = {}  # id(stream) -> connection, in accepting order

    # ------------------------------------------------------------------ tornado's server calls these
    def accept(self, stream: IOStream, address: Any) -> bool:
        """A new connection: True to serve it (an older waiting one may have been evicted for it), False
        when it must be closed unanswered (every slot busy)."""
        peer = _peer(address)
        if len(self._connections) >= self.limits.max_connections:
            waiting = [c for c in self._connections.values() if not c.busy and not c.closed_by_guard]
            if not waiting:
                self.counters.refused += 1
                self.on_turned_away("connections", peer, f"{self.limits.max_connections} connections open")
                return False
            oldest = min(waiting, key=lambda c: c.accepted)
            self.counters.evicted += 1
            self.on_turned_away("evicted", oldest.peer, "closed while waiting: its slot was needed")
            self._close(oldest)
        connection = _Connection(stream, address, peer, self.loop.time())
        connection.timer = self.loop.call_later(self.limits.timeout_s, self._expire, connection)
        self._connections[id(stream)] = connection
        self.counters.accepted += 1
        self.counters.open = len(self._connections)
        return True

    def closed(self, stream: IOStream | None) -> None:
        """Tornado closed ``stream`` (the peer went, tornado's own timeout, our close): forget it. A head
        over :data:`MAX_HEADER` (tornado closes it with an ``UnsatisfiableReadError``) is reported."""
        if stream is None:
            return
        connection = self._connections.pop(id(stream), None)
        self.counters.open = len(self._connections)
        if connection is None:
            return
        self._cancel(connection)
        if connection.closed_by_guard or connection.busy:
            return
        if isinstance(stream.error, UnsatisfiableReadError):
            self.on_turned_away("request", connection.peer, f"a request head over {MAX_HEADER} bytes")
        elif self.loop.time() - connection.accepted >= self.limits.timeout_s * 0.999:
            # tornado's own phase timeout, due at the same moment as ours, came first
            self.counters.timed_out += 1
            self.on_turned_away("timeout", connection.peer, self._timeout_detail())

    # ------------------------------------------------------------------ handlers call these
    def busy(self, stream: IOStream | None) -> None:
        """``stream``'s request is complete and being answered: no longer evictable, no request
        deadline."""
        connection = self._find(stream)
        if connection is not None and not connection.busy:
            connection.busy = True
            self._cancel(connection)

    def answered(self, stream: IOStream | None) -> None:
        """The answer is written (to tornado's buffer): the client has ``timeout_s`` to read it."""
        connection = self._find(stream)
        if connection is not None:
            self._cancel(connection)
            connection.timer = self.loop.call_later(self.limits.timeout_s, self._abandon, connection)

    def malformed(self, address: Any, detail: str) -> None:
        """Tornado refused a request from ``address`` as malformed (answering a bare 400): reported, unless
        a handler had already answered that connection (tornado then refuses the body it would have
        read, and the request was reported by the handler)."""
        connection = next((c for c in self._connections.values() if c.address == address), None)
        if connection is not None and connection.busy:
            return
        self.on_turned_away("request", _peer(address), f"malformed request: {detail}"[:200])

    def close_all(self) -> None:
        for connection in list(self._connections.values()):
            self._close(connection)

    # ------------------------------------------------------------------ inside
    def _find(self, stream: IOStream | None) -> _Connection | None:
        return None if stream is None else self._connections.get(id(stream))

    def _expire(self, connection: _Connection) -> None:
        connection.timer = None
        if connection.busy or connection.closed_by_guard or connection.stream.closed():
            return
        self.counters.timed_out += 1
        self.on_turned_away("timeout", connection.peer, self._timeout_detail())
        self._close(connection)

    def _abandon(self, connection: _Connection) -> None:
        connection.timer = None
        if not connection.stream.closed():
            self.counters.answers_abandoned += 1
            self._close(connection)

    def _timeout_detail(self) -> str:
        return f"no complete request within {self.limits.timeout_s:g} s of connecting"

    def _close(self, connection: _Connection) -> None:
        connection.closed_by_guard = True
        self._cancel(connection)
        connection.stream.close()

    def _cancel(self, connection: _Connection) -> None:
        if connection.timer is not None:
            self.loop.remove_timeout(connection.timer)
            connection.timer = None


def _peer(address: Any) -> str:
    if isinstance(address, tuple) and address:
        return str(address[0])
    return str(address or "")


class TornadoReports(logging.Filter):
    """A filter on ``tornado.general``: a record about a refused request (``Malformed HTTP message``,
    ``Unsatisfiable read``, ``Timeout reading body``) logged from a ground-station server's thread is
    reported to that server and not printed; any other record passes if its level would have.

    Tornado logs those at INFO, and a logger drops records below its level before any filter sees them:
    installing the filter sets ``tornado.general`` to INFO, and the filter then applies the level the
    logger would have had (its parent ``tornado``'s, read at each record) to every other record."""

    _lock = threading.Lock()
    _servers: dict[int, Callable[[Any, str], None]] = {}  # thread id -> its guard's malformed()
    _installed = False

    @classmethod
    def register(cls, malformed: Callable[[Any, str], None]) -> None:
        """The calling thread (a server's IOLoop thread) reports to ``malformed(address, detail)``."""
        with cls._lock:
            cls._servers[threading.get_ident()] = malformed
            if not cls._installed:
                general = logging.getLogger("tornado.general")
                general.setLevel(min(general.getEffectiveLevel(), logging.INFO))
                general.addFilter(cls())
                cls._installed = True

    @classmethod
    def unregister(cls) -> None:
        with cls._lock:
            cls._servers.pop(threading.get_ident(), None)

    def filter(self, record: logging.LogRecord) -> bool:
        report = self._servers.get(threading.get_ident())
        message = str(record.msg)
        if report is not None and message.startswith("Malformed HTTP message"):
            args = record.args if isinstance(record.args, tuple) else ()
            address = getattr(args[0], "address", None) if args else None
            report(address, str(args[1]) if len(args) > 1 else "")
            return False
        if report is not None and message.startswith(("Unsatisfiable read", "Timeout reading body")):
            return False  # reported by ConnectionGuard.closed / its own deadline
        return record.levelno >= logging.getLogger("tornado").getEffectiveLevel()
