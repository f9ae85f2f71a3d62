"""The ground station's earlier server, kept as the benchmark's peer (``bench/bench_gcs.py``): Python's
``http.server`` (``ThreadingHTTPServer``, one thread per connection) under the phone receiver's guard
(:mod:`hil.link.sources.http_guard`), serving the same routes from the same hub, access checks and uplink
as :class:`hil.gcs.server.GcsServer` (which replaced it: docs/gcs.md says why). Not used by ``hil``;
``GroundStation(..., server_class=ThreadedGcsServer)`` runs a station on it.
"""

from __future__ import annotations

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
from urllib.parse import parse_qs, urlsplit

from hil.gcs.access import Access
from hil.gcs.hub import Hub
from hil.gcs.uplink import Uplink, UplinkRefused
from hil.link.sources.http_guard import BodyError, GuardedHandler, GuardedHTTPServer, HttpLimits
from protocol.errors import InputFormatError

logger = logging.getLogger(__name__)

from hil.gcs.server import KEEPALIVE_S, LIMITS, MAX_STREAMS, SEND_TIMEOUT_S  # noqa: E402 - the same limits

_STATIC_NAME = re.compile(r"^[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*$")
_TYPES = {
    ".js": "text/javascript",
    ".css": "text/css",
    ".html": "text/html",
    ".png": "image/png",
    ".txt": "text/plain",
    ".svg": "image/svg+xml",
}


class ThreadedGcsServer(GuardedHTTPServer):
    """The ground station's server on ``host``:``port``, under ``limits`` (:data:`LIMITS` by default)."""

    allow_reuse_address = True

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
        self.address_family = socket.AF_INET6 if ":" in host else socket.AF_INET
        super().__init__((host, port), _Handler, limits, self.turned_away)
        self.access = Access(access_token, host, self.server_address[1])
        self.hub = hub
        self.uplink = uplink
        self.info = info
        self.extra_stats = stats
        self.lock = threading.Lock()
        self.rejected: Counter[str] = Counter()
        self.streams = 0
        self.requests = 0
        self.static = resources.files("hil.gcs") / "static"
        self.thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        return int(self.server_address[1])

    def start(self) -> None:
        self.thread = threading.Thread(
            target=self.serve_forever,
            kwargs={"poll_interval": 0.2},
            name=f"gcs-http :{self.port}",
            daemon=True,
        )
        self.thread.start()

    def stop(self) -> None:
        self.hub.close()
        self.shutdown()
        self.server_close()
        self.close_connections()
        if self.thread is not None:
            self.thread.join(timeout=5.0)

    def counters(self) -> dict[str, Any]:
        with self.lock:
            return {
                "requests": self.requests,
                "streams_open": self.streams,
                "rejected": dict(self.rejected),
                "connections_open": self.active,
                "connections_refused": self.refused,
                "connections_evicted": self.evicted,
            }

    def turned_away(self, reason: str, remote: str, detail: str = "") -> None:
        """A request or connection turned away — by a handler (``host``, ``origin``, ``token``, ``format``,
        ``size``, ``path``, ``busy``) or the guard (``timeout``, ``evicted``, ``connections``, ``request``,
        ``error``): counted, and logged in the run's events when there is a run (docs/gcs.md: an attempt
        leaves a trace)."""
        with self.lock:
            self.rejected[reason] += 1
        if self.uplink is not None:
            self.uplink.reject(reason, remote, detail[:300])


class _Handler(GuardedHandler):
    server: ThreadedGcsServer
    protocol_version = "HTTP/1.0"
    server_version = "vscmg-hil-gcs"

    # ------------------------------------------------------------------ routing
    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        self._count()
        url = urlsplit(self.path)
        if not self.server.access.host_ok(self.headers.get("Host")):
            return self._refuse(
                HTTPStatus.FORBIDDEN, "host", "Host header is not this server's loopback name"
            )
        if url.path in ("/", "/index.html"):
            return self._static("index.html")
        if url.path == "/favicon.ico":
            return self._reply(HTTPStatus.NO_CONTENT, b"", "text/plain")
        if url.path.startswith("/static/"):
            return self._static(url.path.removeprefix("/static/"))
        if url.path.startswith("/api/"):
            try:
                token = parse_qs(url.query).get("token", [None])[0] or self._header_token()
            except ValueError:  # parse_qs refuses more than max_num_fields; a bad query is no token
                token = None
            if not self._api_allowed(token):
                return None
            if url.path == "/api/stream":
                return self._stream()
            if url.path == "/api/info":
                return self._json(HTTPStatus.OK, self.server.info() or {})
            if url.path == "/api/stats":
                return self._json(HTTPStatus.OK, self.server.extra_stats())
        return self._json(HTTPStatus.NOT_FOUND, {"error": f"no such page: {url.path}"})

    def do_POST(self) -> None:  # noqa: N802
        self._count()
        url = urlsplit(self.path)
        uplink = self.server.uplink
        remote = self.address_string()
        if url.path != "/api/command":
            return self._refuse(HTTPStatus.NOT_FOUND, "path", f"no such endpoint: {url.path[:80]}")
        if not self.server.access.host_ok(self.headers.get("Host")):
            return self._refuse(
                HTTPStatus.FORBIDDEN, "host", "Host header is not this server's loopback name"
            )
        if not self._api_allowed(self._header_token()):
            return None
        try:
            body = self.read_body(f"POST {url.path} from {remote}")
        except BodyError as exc:
            if self.server.was_evicted(self.connection):
                return None  # its slot went to a new connection: reported as evicted
            reason = "size" if exc.status == HTTPStatus.REQUEST_ENTITY_TOO_LARGE else "format"
            return self._refuse(HTTPStatus(exc.status), reason, exc.detail)
        if uplink is None:
            return self._json(HTTPStatus.CONFLICT, {"error": "a replay takes no commands"})
        if (self.headers.get("Content-Type") or "").split(";")[0].strip() != "application/json":
            return self._refuse(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "format", "send application/json")
        try:
            command = uplink.submit(body, remote)
        except UplinkRefused as exc:  # no run yet, or the run has ended (as hil.gcs.server answers)
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

    def do_OPTIONS(self) -> None:  # noqa: N802
        """A CORS preflight: only a foreign page sends one, and none is allowed (no CORS headers)."""
        self._count()
        origin = self.headers.get("Origin")
        self._refuse(HTTPStatus.FORBIDDEN, "origin", f"cross-origin requests are not accepted ({origin})")

    # ------------------------------------------------------------------ checks
    def _header_token(self) -> str | None:
        auth = self.headers.get("Authorization") or ""
        scheme, _, value = auth.partition(" ")
        return value.strip() if scheme.lower() == "token" and value.strip() else None

    def _api_allowed(self, token: str | None) -> bool:
        """The Origin first (a foreign page is refused whatever it sends), then the token."""
        access = self.server.access
        origin = self.headers.get("Origin")
        if not access.origin_ok(origin, self.headers.get("Host")):
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

    # ------------------------------------------------------------------ answers
    def _count(self) -> None:
        with self.server.lock:
            self.server.requests += 1

    def _refuse(self, status: HTTPStatus, reason: str, message: str, detail: str | None = None) -> None:
        """Answer ``status`` saying ``message``; the request is counted and logged as turned away
        (``detail``, default the message, goes into the record)."""
        self.server.turned_away(reason, self.address_string(), message if detail is None else detail)
        self.close_connection = True
        self._json(status, {"error": message, "reason": reason})

    def _json(self, status: HTTPStatus, value: Any) -> None:
        self._reply(status, json.dumps(value, default=str).encode(), "application/json")

    def _reply(self, status: HTTPStatus, body: bytes, content_type: str) -> None:
        self.deadline_for_answer()  # a client that does not read its answer cannot hold the thread
        try:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.end_headers()
            self.wfile.write(body)
        except OSError:  # the browser went away or stopped reading: nothing to tell it
            self.close_connection = True

    def _static(self, name: str) -> None:
        if not _STATIC_NAME.match(name) or ".." in name.split("/"):
            return self._json(HTTPStatus.NOT_FOUND, {"error": "no such file"})
        resource = self.server.static.joinpath(*name.split("/"))
        try:
            body = resource.read_bytes()
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            return self._json(HTTPStatus.NOT_FOUND, {"error": f"no such file: {name}"})
        suffix = "." + name.rsplit(".", 1)[-1] if "." in name else ""
        kind = _TYPES.get(suffix) or mimetypes.guess_type(name)[0] or "application/octet-stream"
        return self._reply(HTTPStatus.OK, body, kind)

    def _stream(self) -> None:
        server = self.server
        with server.lock:
            if server.streams >= MAX_STREAMS:
                full = True
            else:
                full = False
                server.streams += 1
        if full:
            return self._refuse(
                HTTPStatus.SERVICE_UNAVAILABLE, "streams", f"{MAX_STREAMS} streams already open"
            )
        hub = server.hub
        hub.count_stream(+1)
        try:
            self.connection.settimeout(SEND_TIMEOUT_S)
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Accel-Buffering", "no")
            self.end_headers()
            self.wfile.write(b"retry: 1000\n\n")
            reader = hub.reader()
            while True:
                data = reader.read(KEEPALIVE_S)
                if data is None:
                    self.wfile.write(b"event: bye\ndata: {}\n\n")
                    break
                data = data or b": keep-alive\n\n"
                self.wfile.write(data)
                hub.count_sent(len(data))
        except (BrokenPipeError, ConnectionResetError, TimeoutError, OSError):
            pass  # the browser went away or stopped reading
        finally:
            hub.count_stream(-1)
            with server.lock:
                server.streams -= 1
