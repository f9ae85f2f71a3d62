"""The ground station's HTTP server, on tornado (a maintained asynchronous server; what Jupyter and Dask's
dashboard run on): the page and its files, the downlink as Server-Sent Events, the uplink as JSON POSTs.
One thread, its own IOLoop; no thread per connection (docs/gcs.md, "How it is built", says why tornado
and why SSE rather than a WebSocket).

Routes (every ``/api/`` route needs the token; :mod:`hil.gcs.access` has the checks):

``GET  /``                      the page (it reads the token from its own URL)
``GET  /static/<file>``         the page's scripts, styles and vendored libraries (``hil/gcs/static/``)
``GET  /api/stream?token=T``    the downlink (``text/event-stream``, :mod:`hil.gcs.wire`)
``GET  /api/info?token=T``      the run's ``info`` as JSON (503, ``Retry-After``, before a live run starts)
``GET  /api/stats?token=T``     the server's counters (streams, bytes sent, rejections, the feed's drops)
``POST /api/command``           a command (``Authorization: token T``, ``Content-Type: application/json``)
``POST /api/ack``               an alarm acknowledged by the operator (same headers; :mod:`hil.gcs.uplink`)

Answers: 403 for a foreign ``Origin`` (checked first; a CORS preflight is always refused) or, on a
loopback server, a non-loopback ``Host``; 401 without the right token; 400 for a malformed command (saying
what is wrong); 411/413/501 for a body refused from its headers (no length, over
:data:`~hil.gcs.uplink.MAX_BODY`, another transfer coding); 409 when there is no uplink (a replay) or no
run to carry the command out (``"reason": "no_run"`` before a live run has started, ``"ended"`` after its
loop ended); 503 when the command inbox or the stream limit is full; 202 with the command's id when it is
queued.

Limits (:data:`LIMITS`): tornado's own settings where it has them (:func:`hil.gcs.guard.tornado_settings`:
each phase's timeout, head and body sizes, its read buffer, one request per connection) and
:class:`~hil.gcs.guard.ConnectionGuard` for what it lacks (the connection cap with eviction, the
whole-request deadline, a report for each connection turned away). Every request or connection turned
away — each 4xx/5xx but a GET's 404 and the inbox's 503 (counted by the uplink) — is counted
(``/api/stats``) and, on a live run, logged in ``events.jsonl`` as a ``rejected`` command record with its
reason (:meth:`GcsServer.turned_away`). Nothing is printed: tornado's access log is off, its reports of
refused requests are taken by :class:`~hil.gcs.guard.TornadoReports`, a handler's exception is reported
(``error``).
"""

from __future__ import annotations

import asyncio
import errno
import json
import logging
import mimetypes
import re
import socket
import threading
from collections import Counter
from collections.abc import Callable
from http import HTTPStatus
from importlib import resources
from typing import Any

from tornado import gen, httputil, web
from tornado.httpserver import HTTPServer
from tornado.ioloop import IOLoop
from tornado.iostream import IOStream, StreamClosedError
from tornado.locks import Condition
from tornado.netutil import bind_sockets

from hil.gcs.access import Access
from hil.gcs.guard import ConnectionGuard, TornadoReports, tornado_settings
from hil.gcs.hub import READ_MAX, Hub
from hil.gcs.uplink import MAX_BODY, Uplink, UplinkRefused
from hil.link.sources.http_guard import BACKLOG, BodyError, HttpLimits, content_length
from protocol.errors import InputFormatError

logger = logging.getLogger(__name__)

MAX_STREAMS = 16  # concurrent downlink streams
KEEPALIVE_S = 10.0  # an SSE comment when nothing else was sent for this long
SEND_TIMEOUT_S = 30.0  # a browser that stops reading for this long loses its stream (the hub never waits)
REQUEST_TIMEOUT_S = 10.0  # s: from connecting to a request's last byte
MAX_CONNECTIONS = 32  # open at once: MAX_STREAMS streams and room for the page's files and commands
LIMITS = HttpLimits(max_body=MAX_BODY, timeout_s=REQUEST_TIMEOUT_S, max_connections=MAX_CONNECTIONS)
STOP_TIMEOUT_S = 5.0
_STATIC_NAME = re.compile(r"^[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*$")
_TYPES = {
    ".js": "text/javascript",
    ".css": "text/css",
    ".html": "text/html",
    ".png": "image/png",
    ".txt": "text/plain",
    ".svg": "image/svg+xml",
}

Submit = Callable[[bytes, str], Any]


class GcsServer:
    """The ground station's server on ``host``:``port`` (0: a free one), under ``limits``; binds at once
    (an ``OSError`` here, EADDRINUSE among them, is the caller's), serves from :meth:`start` on its own
    thread until :meth:`stop`. ``acks`` takes an alarm acknowledgement's body (``POST /api/ack``)."""

    def __init__(
        self,
        host: str,
        port: int,
        access_token: str,
        hub: Hub,
        uplink: Uplink | None,
        info: Callable[[], dict[str, Any] | None],
        stats: Callable[[], dict[str, Any]],
        limits: HttpLimits = LIMITS,
    ) -> None:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._sockets = bind_sockets(port, host or None, family=family, backlog=BACKLOG)
        self.limits = limits
        self.access = Access(access_token, host, self.port)
        self.hub = hub
        self.uplink = uplink
        self.info = info
        self.extra_stats = stats
        self.static = resources.files("hil.gcs") / "static"
        self.lock = threading.Lock()
        self.rejected: Counter[str] = Counter()
        self.requests = 0
        self.streams = 0
        self._asyncio = asyncio.new_event_loop()
        self.loop: IOLoop | None = None
        self.guard: ConnectionGuard | None = None
        self._http: HTTPServer | None = None
        self._wake: Condition | None = None
        self._ready = threading.Event()
        self.thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        return int(self._sockets[0].getsockname()[1])

    # ------------------------------------------------------------------ life
    def start(self) -> None:
        self.thread = threading.Thread(target=self._serve, name=f"gcs-http :{self.port}", daemon=True)
        self.thread.start()
        if not self._ready.wait(STOP_TIMEOUT_S):
            raise RuntimeError("the ground station's server thread did not start")

    def _serve(self) -> None:
        asyncio.set_event_loop(self._asyncio)
        loop = IOLoop.current()
        self.loop = loop
        guard = ConnectionGuard(loop, self.limits, self.turned_away)
        self.guard = guard
        TornadoReports.register(guard.malformed)
        self._wake = Condition()
        self.hub.watch(self._hub_changed)
        app = web.Application(_routes(self), log_function=_no_access_log, compress_response=False)
        self._http = _GuardedHTTPServer(app, **tornado_settings(self.limits))
        self._http.guard = guard
        self._http.add_sockets(self._sockets)
        self._ready.set()
        try:
            loop.start()
        finally:
            TornadoReports.unregister()

    def _hub_changed(self) -> None:
        """From the pump's thread: wake every stream on the IOLoop."""
        loop, wake = self.loop, self._wake
        if loop is not None and wake is not None:
            loop.add_callback(wake.notify_all)

    def stop(self) -> None:
        """Close the listening sockets and every connection, stop the loop, join its thread."""
        self.hub.close()
        loop = self.loop
        if loop is None or self.thread is None:  # never started: its sockets and event loop are all it holds
            for s in self._sockets:
                s.close()
            self._asyncio.close()
            return

        def shut() -> None:
            if self._http is not None:
                self._http.stop()
            if self.guard is not None:
                self.guard.close_all()
            loop.add_callback(loop.stop)

        loop.add_callback(shut)
        self.thread.join(STOP_TIMEOUT_S)
        if not self.thread.is_alive():
            loop.close(all_fds=True)

    # ------------------------------------------------------------------ counters and reports
    def counters(self) -> dict[str, Any]:
        guard = self.guard
        g = guard.counters if guard is not None else None
        with self.lock:
            return {
                "requests": self.requests,
                "streams_open": self.streams,
                "rejected": dict(self.rejected),
                "connections_open": g.open if g else 0,
                "connections_refused": g.refused if g else 0,
                "connections_evicted": g.evicted if g else 0,
                "answers_abandoned": g.answers_abandoned if g else 0,
            }

    def turned_away(self, reason: str, remote: str, detail: str = "") -> None:
        """A request or connection turned away — by a handler (``host``, ``origin``, ``token``, ``format``,
        ``size``, ``path``, ``streams``, ``method``; a stream cut off unread: ``stalled``) or the guard
        (``timeout``, ``evicted``, ``connections``, ``request``, ``error``): counted, and logged in the
        run's events when there is a run (docs/gcs.md: an attempt leaves a trace)."""
        with self.lock:
            self.rejected[reason] += 1
        if self.uplink is not None:
            self.uplink.reject(reason, remote, detail[:300])


class _GuardedHTTPServer(HTTPServer):
    """Tornado's HTTP server with :class:`~hil.gcs.guard.ConnectionGuard` told of each connection."""

    guard: ConnectionGuard

    def handle_stream(self, stream: IOStream, address: tuple[Any, ...]) -> None:
        if not self.guard.accept(stream, address):
            stream.close()
            return
        super().handle_stream(stream, address)

    def on_close(self, server_conn: object) -> None:
        super().on_close(server_conn)
        self.guard.closed(getattr(server_conn, "stream", None))


def _no_access_log(handler: web.RequestHandler) -> None:
    """Tornado's access log is off: refusals are counted and logged in the run's events instead."""


def _routes(server: GcsServer) -> list[tuple[str, type[web.RequestHandler], dict[str, Any]]]:
    kw = {"server": server}
    return [
        (r"/(?:index\.html)?", _Page, kw),
        (r"/favicon\.ico", _Favicon, kw),
        (r"/static/(.*)", _Static, kw),
        (r"/api/stream", _Stream, kw),
        (r"/api/info", _Info, kw),
        (r"/api/stats", _Stats, kw),
        (r"/api/command", _Command, kw),
        (r"/api/ack", _Ack, kw),
        (r".*", _Base, kw),
    ]


class _Base(web.RequestHandler):
    """Every route's checks and answers; on its own, the answer to a path that does not exist."""

    SUPPORTED_METHODS = ("GET", "POST", "OPTIONS")  # type: ignore[assignment]
    server: GcsServer

    def initialize(self, server: GcsServer) -> None:
        self.server = server
        self._answered = False

    # ------------------------------------------------------------------ tornado's hooks
    def set_default_headers(self) -> None:
        self.set_header("Server", "vscmg-hil-gcs")
        self.set_header("Cache-Control", "no-store")
        self.set_header("X-Content-Type-Options", "nosniff")

    def prepare(self) -> None:
        with self.server.lock:
            self.server.requests += 1
        self._busy()
        if self.request.method != "POST" and not self._host_ok():
            self._refuse(HTTPStatus.FORBIDDEN, "host", "Host header is not this server's loopback name")

    def on_finish(self) -> None:
        guard = self.server.guard
        if guard is not None:
            guard.answered(self._stream())

    def write_error(self, status_code: int, **kwargs: Any) -> None:
        """An answer tornado makes itself (a method this route does not take: 405; a path whose
        %-escapes are not UTF-8: 400) or after a handler's exception (500), as JSON like every other; each
        reported (a 400 was answered ``"reason": "error"`` and neither counted nor logged)."""
        remote = self.request.remote_ip or ""
        if status_code == HTTPStatus.METHOD_NOT_ALLOWED:
            reason = "method"
            self.server.turned_away(reason, remote, f"{self.request.method}")
        elif status_code == HTTPStatus.BAD_REQUEST:
            reason = "path"
            exc = kwargs.get("exc_info", (None, None))[1]
            said = getattr(exc, "log_message", None) or self._reason
            self.server.turned_away(reason, remote, f"{said} ({self.request.path[:120]})")
        else:
            reason = "error"  # reported by log_exception
        self.finish({"error": self._reason, "reason": reason})

    def log_exception(self, typ: Any, value: Any, tb: Any) -> None:
        """A handler's exception is reported (``error``), never printed."""
        if isinstance(value, web.HTTPError):
            return
        self.server.turned_away(
            "error", self.request.remote_ip or "", _error_detail(value, self.request.path)
        )

    # ------------------------------------------------------------------ the default route
    def get(self, *args: str) -> None:
        self._json(HTTPStatus.NOT_FOUND, {"error": f"no such page: {self.request.path[:200]}"})

    def post(self, *args: str) -> None:
        self._refuse(HTTPStatus.NOT_FOUND, "path", f"no such endpoint: {self.request.path[:80]}")

    def options(self, *args: str) -> None:
        """A CORS preflight: only a foreign page sends one, and none is allowed (no CORS headers)."""
        origin = self.request.headers.get("Origin")
        self._refuse(HTTPStatus.FORBIDDEN, "origin", f"cross-origin requests are not accepted ({origin})")

    # ------------------------------------------------------------------ checks
    def _host_ok(self) -> bool:
        return self.server.access.host_ok(self.request.headers.get("Host"))

    def _header_token(self) -> str | None:
        auth = self.request.headers.get("Authorization") or ""
        scheme, _, value = auth.partition(" ")
        return value.strip() if scheme.lower() == "token" and value.strip() else None

    def _api_allowed(self, token: str | None) -> bool:
        """The Origin first (a foreign page is refused whatever it sends), then the token."""
        access = self.server.access
        origin = self.request.headers.get("Origin")
        if not access.origin_ok(origin, self.request.headers.get("Host")):
            self._refuse(HTTPStatus.FORBIDDEN, "origin", f"requests from {origin} are not accepted")
            return False
        if not access.token_ok(token):
            self._refuse(
                HTTPStatus.UNAUTHORIZED,
                "token",
                "missing or wrong token (see the URL printed at start)",
                "missing" if token is None else "wrong",
            )
            return False
        return True

    def _query_token(self) -> str | None:
        return self.get_query_argument("token", None) or self._header_token()

    # ------------------------------------------------------------------ answers
    def _stream(self) -> IOStream | None:
        connection = self.request.connection
        return getattr(connection, "stream", None)

    def _busy(self) -> None:
        guard = self.server.guard
        if guard is not None:
            guard.busy(self._stream())

    def _refuse(self, status: HTTPStatus, reason: str, message: str, detail: str | None = None) -> None:
        """Answer ``status`` saying ``message``; the request is counted and logged as turned away
        (``detail``, default the message, goes into the record)."""
        self._busy()
        remote = self.request.remote_ip or ""
        self.server.turned_away(reason, remote, message if detail is None else detail)
        self._json(status, {"error": message, "reason": reason})

    def _json(self, status: HTTPStatus, value: Any) -> None:
        self._reply(status, json.dumps(value, default=str).encode(), "application/json")

    def _reply(self, status: HTTPStatus, body: bytes, content_type: str) -> None:
        if self._finished:
            return
        self._answered = True
        self.set_status(int(status))
        self.set_header("Content-Type", content_type)
        self.finish(body)


_NO_SUCH_FILE = (FileNotFoundError, IsADirectoryError, NotADirectoryError)
_NAME_ERRNOS = (errno.ENAMETOOLONG, errno.ELOOP)  # about the name the client asked for, not our files


def _error_detail(exc: BaseException, path: str) -> str:
    """A report's detail: the error first, then where (the path cut to 120 characters), so the record,
    itself cut to 300 characters, says which error even when the path is 6 kB."""
    cut = path if len(path) <= 120 else f"{path[:120]}… ({len(path)} characters)"
    return f"{type(exc).__name__}: {str(exc)[:120]} at {cut}"


class _Page(_Base):
    def get(self, *args: str) -> None:
        self._static("index.html")

    def _static(self, name: str) -> None:
        if not _STATIC_NAME.match(name) or ".." in name.split("/"):
            return self._json(HTTPStatus.NOT_FOUND, {"error": "no such file"})
        resource = self.server.static.joinpath(*name.split("/"))
        try:
            body = resource.read_bytes()
        except OSError as exc:
            # Whatever the OS says of a name the client wrote, the answer is that there is no such file —
            # a name past PATH_MAX (ENAMETOOLONG) as a missing one; an error that is not about the name (the
            # page's own files unreadable: EACCES, EIO) is also reported, saying which.
            if not isinstance(exc, _NO_SUCH_FILE) and exc.errno not in _NAME_ERRNOS:
                self.server.turned_away("error", self.request.remote_ip or "", _error_detail(exc, name))
            return self._json(HTTPStatus.NOT_FOUND, {"error": f"no such file: {name[:80]}"})
        suffix = "." + name.rsplit(".", 1)[-1] if "." in name else ""
        kind = _TYPES.get(suffix) or mimetypes.guess_type(name)[0] or "application/octet-stream"
        return self._reply(HTTPStatus.OK, body, kind)


class _Static(_Page):
    def get(self, *args: str) -> None:
        self._static(args[0] if args else "")


class _Favicon(_Base):
    def get(self, *args: str) -> None:
        self.set_status(HTTPStatus.NO_CONTENT)
        self.finish()


class _Info(_Base):
    def get(self, *args: str) -> None:
        if not self._api_allowed(self._query_token()):
            return
        info = self.server.info()
        if info is None:  # a live station whose run has not started: say so, never an empty "info"
            self.set_header("Retry-After", "1")
            waiting = {"state": "waiting", "error": "no run has started yet"}
            self._json(HTTPStatus.SERVICE_UNAVAILABLE, waiting)
            return
        self._json(HTTPStatus.OK, info)


class _Stats(_Base):
    def get(self, *args: str) -> None:
        if self._api_allowed(self._query_token()):
            self._json(HTTPStatus.OK, self.server.extra_stats())


class _Stream(_Base):
    """The downlink: the hub's chunks as Server-Sent Events, woken by the hub (never a thread waiting)."""

    async def get(self, *args: str) -> None:  # type: ignore[override]  # tornado takes either
        if not self._api_allowed(self._query_token()):
            return
        server = self.server
        with server.lock:
            full = server.streams >= MAX_STREAMS
            if not full:
                server.streams += 1
        if full:
            return self._refuse(
                HTTPStatus.SERVICE_UNAVAILABLE, "streams", f"{MAX_STREAMS} streams already open"
            )
        hub = server.hub
        hub.count_stream(+1)
        try:
            self.set_header("Content-Type", "text/event-stream")
            self.set_header("X-Accel-Buffering", "no")
            await self._send(b"retry: 1000\n\n")
            reader = hub.reader()
            hub.resume(reader, self.request.headers.get("Last-Event-ID"))  # a reconnection: what it missed
            wake = server._wake
            assert wake is not None
            while True:
                data = reader.read(0, READ_MAX)  # a slice at a time: a browser that never reads holds one
                if data is None:
                    await self._send(b"event: bye\ndata: {}\n\n")
                    break
                if data:
                    await self._send(data)
                    hub.count_sent(len(data))
                    continue
                loop = IOLoop.current()
                if not await wake.wait(timeout=loop.time() + KEEPALIVE_S):
                    await self._send(b": keep-alive\n\n")
        except StreamClosedError:
            pass  # the browser went away
        except (gen.TimeoutError, TimeoutError):
            # it stopped reading: cut off (its slot and the slice it held freed), and said — a stream the
            # server drops is counted and logged as every other connection it turns away
            server.turned_away(
                "stalled",
                self.request.remote_ip or "",
                f"its stream was not read for {SEND_TIMEOUT_S:g} s: cut off",
            )
        finally:
            hub.count_stream(-1)
            with server.lock:
                server.streams -= 1
        if not self._finished:
            self.finish()

    async def _send(self, data: bytes) -> None:
        self.write(data)
        await gen.with_timeout(IOLoop.current().time() + SEND_TIMEOUT_S, self.flush())


class _Headers:
    """Tornado's headers as :func:`~hil.link.sources.http_guard.content_length` reads them (the phone
    receiver's rules: one plain decimal number, every copy the same)."""

    def __init__(self, headers: httputil.HTTPHeaders) -> None:
        self.headers = headers

    def get_all(self, name: str, default: list[str]) -> list[str]:
        return self.headers.get_list(name) or default


@web.stream_request_body
class _Command(_Base):
    """``POST /api/command``: checked from its headers before its body is read (origin, token, length,
    type), the body taken in pieces up to :data:`MAX_BODY`, then parsed and queued (:class:`Uplink`)."""

    def prepare(self) -> None:
        with self.server.lock:
            self.server.requests += 1
        self._body = bytearray()
        self._over = False
        if not self._host_ok():
            self._busy()
            return self._refuse(
                HTTPStatus.FORBIDDEN, "host", "Host header is not this server's loopback name"
            )
        if self.request.method != "POST":
            return None
        if not self._api_allowed(self._header_token()):
            return None
        headers = self.request.headers
        codings = [c.strip().lower() for v in headers.get_list("Transfer-Encoding") for c in v.split(",")]
        codings = [c for c in codings if c]
        where = f"POST {self.request.path} from {self.request.remote_ip}"
        try:
            if codings and codings != ["chunked"]:
                raise BodyError(501, f"transfer coding {', '.join(codings)!r} is not supported", where)
            if not codings and content_length(_Headers(headers), MAX_BODY, where) is None:  # type: ignore[arg-type]
                raise BodyError(411, "a POST needs a Content-Length or chunked transfer coding", where)
        except BodyError as exc:
            reason = "size" if exc.status == HTTPStatus.REQUEST_ENTITY_TOO_LARGE else "format"
            return self._refuse(HTTPStatus(exc.status), reason, exc.detail)
        return None

    def data_received(self, chunk: bytes) -> None:
        if self._finished or self._over:
            return  # refused already: the rest is read and dropped (so the answer is not lost to a reset)
        if len(self._body) + len(chunk) > MAX_BODY:
            self._over = True
            self._body.clear()
            return
        self._body += chunk

    def post(self, *args: str) -> None:
        if self._finished:
            return
        self._busy()
        if self._over:
            return self._refuse(
                HTTPStatus.REQUEST_ENTITY_TOO_LARGE, "size", f"a chunked body of more than {MAX_BODY} bytes"
            )
        self._take(bytes(self._body))

    def _take(self, body: bytes) -> None:
        uplink = self.server.uplink
        remote = self.request.remote_ip or ""
        if uplink is None:
            return self._json(HTTPStatus.CONFLICT, {"error": "a replay takes no commands"})
        if not self._json_type():
            return None
        try:
            command = uplink.submit(body, remote)
        except UplinkRefused as exc:  # no run yet, or the run has ended: not the sender's fault, not logged
            return self._json(HTTPStatus.CONFLICT, {"error": str(exc), "reason": exc.reason})
        except InputFormatError as exc:
            return self._refuse(HTTPStatus.BAD_REQUEST, "format", str(exc))
        if command is None:  # counted by the uplink (inbox_full), not a rejection: the sender may retry
            return self._json(
                HTTPStatus.SERVICE_UNAVAILABLE, {"error": "too many commands waiting", "reason": "busy"}
            )
        return self._json(
            HTTPStatus.ACCEPTED, {"id": command.id, "command": command.name, "status": "queued"}
        )

    def _json_type(self) -> bool:
        if (self.request.headers.get("Content-Type") or "").split(";")[0].strip() != "application/json":
            self._refuse(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "format", "send application/json")
            return False
        return True

    def get(self, *args: str) -> None:
        self._json(HTTPStatus.NOT_FOUND, {"error": f"no such page: {self.request.path[:200]}"})


class _Ack(_Command):
    """``POST /api/ack``: ``{"alarm": KEY}`` — the operator acknowledged an alarm (logged as an event on
    the next control tick, :meth:`Uplink.acknowledge`)."""

    def _take(self, body: bytes) -> None:
        uplink = self.server.uplink
        if uplink is None:
            return self._json(HTTPStatus.CONFLICT, {"error": "a replay takes no acknowledgements"})
        if not self._json_type():
            return None
        try:
            ack = uplink.acknowledge(body, self.request.remote_ip or "")
        except UplinkRefused as exc:  # no run yet, or the run has ended: not the sender's fault, not logged
            return self._json(HTTPStatus.CONFLICT, {"error": str(exc), "reason": exc.reason})
        except InputFormatError as exc:
            return self._refuse(HTTPStatus.BAD_REQUEST, "format", str(exc))
        if ack is None:
            return self._json(
                HTTPStatus.SERVICE_UNAVAILABLE,
                {"error": "too many acknowledgements waiting", "reason": "busy"},
            )
        return self._json(HTTPStatus.ACCEPTED, {"alarm": ack["alarm"], "status": "queued"})
