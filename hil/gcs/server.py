"""The ground station's HTTP server: the page and its files, the downlink as Server-Sent Events, the uplink
as JSON POSTs. Standard library only (``http.server``), one thread per request, its own accept thread.

Routes (every ``/api/`` route needs the token; :mod:`hil.gcs.access` has the checks):

``GET  /``                      the page (it reads the token from its own URL)
``GET  /static/<file>``         the page's scripts, styles and vendored libraries (``hil/gcs/static/``)
``GET  /api/stream?token=T``    the downlink (``text/event-stream``, :mod:`hil.gcs.wire`)
``GET  /api/info?token=T``      the run's ``info`` as JSON
``GET  /api/stats?token=T``     the server's counters (streams, bytes sent, rejections, the feed's drops)
``POST /api/command``           a command (``Authorization: token T``, ``Content-Type: application/json``)

Answers: 403 for a foreign ``Origin`` (checked first; a CORS preflight is always refused) or, on a
loopback server, a non-loopback ``Host``; 401 without the right token; 400 for a malformed command (saying
what is wrong); 409 when there is no uplink (a replay); 503 when the command inbox or the stream limit is
full; 202 with the command's id when it is queued.
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
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import parse_qs, urlsplit

from hil.gcs.access import Access
from hil.gcs.hub import Hub
from hil.gcs.uplink import Uplink
from protocol.errors import InputFormatError

logger = logging.getLogger(__name__)

MAX_STREAMS = 16  # concurrent downlink streams (each holds a thread)
KEEPALIVE_S = 10.0  # an SSE comment when nothing else was sent for this long
SEND_TIMEOUT_S = 30.0  # a browser that stops reading for this long loses its stream (the hub never waits)
_STATIC_NAME = re.compile(r"^[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*$")
_TYPES = {".js": "text/javascript", ".css": "text/css", ".html": "text/html", ".png": "image/png",
          ".txt": "text/plain", ".svg": "image/svg+xml"}  # fmt: skip


class GcsHttpServer(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    block_on_close = False

    def __init__(
        self, host: str, port: int, access_token: str, hub: Hub, uplink: Uplink | None,
        info: Callable[[], dict[str, Any] | None], stats: Callable[[], dict[str, Any]],
    ) -> None:  # fmt: skip
        self.address_family = socket.AF_INET6 if ":" in host else socket.AF_INET
        super().__init__((host, port), _Handler)
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
        self.thread = threading.Thread(target=self.serve_forever, kwargs={"poll_interval": 0.2},
                                       name=f"gcs-http :{self.port}", daemon=True)  # fmt: skip
        self.thread.start()

    def stop(self) -> None:
        self.hub.close()
        self.shutdown()
        self.server_close()
        if self.thread is not None:
            self.thread.join(timeout=5.0)

    def counters(self) -> dict[str, Any]:
        with self.lock:
            return {"requests": self.requests, "streams_open": self.streams, "rejected": dict(self.rejected)}


class _Handler(BaseHTTPRequestHandler):
    server: GcsHttpServer
    protocol_version = "HTTP/1.0"
    server_version = "vscmg-hil-gcs"

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base class's name
        logger.debug("%s %s", self.address_string(), format % args)

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
            token = parse_qs(url.query).get("token", [None])[0] or self._header_token()
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
            return self._json(HTTPStatus.NOT_FOUND, {"error": f"no such endpoint: {url.path}"})
        if not self.server.access.host_ok(self.headers.get("Host")):
            if uplink is not None:
                uplink.reject("host", remote, str(self.headers.get("Host")))
            return self._refuse(
                HTTPStatus.FORBIDDEN, "host", "Host header is not this server's loopback name"
            )
        if not self._api_allowed(self._header_token(), uplink):
            return None
        length = self._length()
        if length is None:
            return None
        body = self.rfile.read(length)
        if uplink is None:
            return self._json(HTTPStatus.CONFLICT, {"error": "a replay takes no commands"})
        if (self.headers.get("Content-Type") or "").split(";")[0].strip() != "application/json":
            uplink.reject("format", remote, "Content-Type is not application/json")
            return self._refuse(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "format", "send application/json")
        try:
            command = uplink.submit(body, remote)
        except InputFormatError as exc:
            uplink.reject("format", remote, exc.detail)
            return self._refuse(HTTPStatus.BAD_REQUEST, "format", str(exc))
        if command is None:
            return self._refuse(HTTPStatus.SERVICE_UNAVAILABLE, "busy", "too many commands waiting")
        return self._json(
            HTTPStatus.ACCEPTED, {"id": command.id, "command": command.name, "status": "queued"}
        )

    def do_OPTIONS(self) -> None:  # noqa: N802
        """A CORS preflight: only a foreign page sends one, and none is allowed (no CORS headers)."""
        self._count()
        if self.server.uplink is not None and urlsplit(self.path).path == "/api/command":
            self.server.uplink.reject(
                "origin", self.address_string(), f"preflight from {self.headers.get('Origin')}"
            )
        self._refuse(HTTPStatus.FORBIDDEN, "origin", "cross-origin requests are not accepted")

    # ------------------------------------------------------------------ checks
    def _header_token(self) -> str | None:
        auth = self.headers.get("Authorization") or ""
        scheme, _, value = auth.partition(" ")
        return value.strip() if scheme.lower() == "token" and value.strip() else None

    def _api_allowed(self, token: str | None, uplink: Uplink | None = None) -> bool:
        """The Origin first (a foreign page is refused whatever it sends), then the token."""
        access = self.server.access
        remote = self.address_string()
        origin = self.headers.get("Origin")
        if not access.origin_ok(origin, self.headers.get("Host")):
            if uplink is not None:
                uplink.reject("origin", remote, str(origin))
            self._refuse(HTTPStatus.FORBIDDEN, "origin", f"requests from {origin} are not accepted")
            return False
        if not access.token_ok(token):
            if uplink is not None:
                uplink.reject("token", remote, "missing" if token is None else "wrong")
            self._refuse(
                HTTPStatus.UNAUTHORIZED, "token", "missing or wrong token (see the URL printed at start)"
            )
            return False
        return True

    def _length(self) -> int | None:
        try:
            length = int(self.headers.get("Content-Length") or "0")
        except ValueError:
            length = -1
        if not 0 <= length <= 4096:
            self._refuse(HTTPStatus.BAD_REQUEST, "format", "Content-Length must be 0-4096")
            return None
        return length

    # ------------------------------------------------------------------ answers
    def _count(self) -> None:
        with self.server.lock:
            self.server.requests += 1

    def _refuse(self, status: HTTPStatus, reason: str, message: str) -> None:
        with self.server.lock:
            self.server.rejected[reason] += 1
        self._json(status, {"error": message, "reason": reason})

    def _json(self, status: HTTPStatus, value: Any) -> None:
        self._reply(status, json.dumps(value, default=str).encode(), "application/json")

    def _reply(self, status: HTTPStatus, body: bytes, content_type: str) -> None:
        try:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.end_headers()
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the browser went away: nothing to tell it

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
            return self._refuse(HTTPStatus.SERVICE_UNAVAILABLE, "busy", f"{MAX_STREAMS} streams already open")
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
