"""The ground station: a source (a live run's feed, or a run directory), the pump thread that turns what the
source has into downlink chunks ~30 times a second, the hub that holds them, and the HTTP server.

::

    control thread ──row/event──► LiveFeed (bounded deque: drop and count) ─┐
    run directory ──────────────► RunDirSource (complete lines) ────────────┤ poll, 30 Hz
                                                                           ▼
                                               pump thread: encode once ─► Hub (history, byte budget)
                                                                           │ one cursor per browser
    browser ◄── SSE ── tornado IOLoop thread (woken by the hub) ◄──────────┘
    browser ── POST /api/command ──► Uplink inbox (bounded) ──► control thread, next tick

Nothing on the right of the feed can delay the control thread: the feed is the only thing it touches, and
it never waits. The pump's own errors are stored and raised by :meth:`GroundStation.check` (and shown in
the page), never swallowed.
"""

from __future__ import annotations

import errno
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any, Protocol

from hil.gcs.access import is_loopback, new_token, parse_bind, url_host
from hil.gcs.compare import CompareSource
from hil.gcs.hub import DEFAULT_BUDGET, Hub
from hil.gcs.live import LiveFeed
from hil.gcs.rundir import STOPPED, RunDirSource
from hil.gcs.server import LIMITS, GcsServer
from hil.gcs.uplink import Uplink
from hil.gcs.wire import Batch, dumps, encode_batch, sse
from hil.link.sources.http_guard import HttpLimits
from hil.threads import ThreadError
from protocol.errors import LinkError

logger = logging.getLogger(__name__)

PUMP_HZ = 30.0  # downlink chunks per second (the page's update rate follows)
PORT_TRIES = 10  # without an explicit port, the next ones are tried when the default is taken
LINGER_S = 2.0  # at close, how long streams may take to send what they have left


class Source(Protocol):
    def poll(self) -> Batch: ...


class Server(Protocol):
    """What the station needs of its HTTP server (:class:`~hil.gcs.server.GcsServer`)."""

    @property
    def port(self) -> int: ...

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def counters(self) -> dict[str, Any]: ...


ServerClass = Callable[..., Server]


class GroundStation:
    """Serve ``source`` on ``bind`` (``HOST:PORT``, default loopback :data:`hil.gcs.access.DEFAULT_PORT`);
    ``uplink`` takes commands (a live run's); ``limits`` bound what a client may hold of the server
    (:data:`hil.gcs.server.LIMITS`); ``server_class`` is the HTTP server (:class:`~hil.gcs.server.GcsServer`;
    ``bench/bench_gcs.py`` passes the earlier threaded one to compare). Starts at once; :meth:`close` (or
    ``with``) stops it."""

    def __init__(
        self,
        source: Source,
        *,
        bind: str | None = None,
        token: str | None = None,
        uplink: Uplink | None = None,
        budget: int = DEFAULT_BUDGET,
        limits: HttpLimits = LIMITS,
        server_class: ServerClass = GcsServer,
    ) -> None:
        host, port, explicit = parse_bind(bind)
        self.server_class = server_class
        self.limits = limits
        self.source = source
        self.uplink = uplink
        self.token = token or new_token()
        self.hub = Hub(budget, host_clock=time.monotonic)  # the clock of a live feed's ``host_time``
        self.info: dict[str, Any] | None = None
        self._said: tuple[Any, Any] = (None, None)  # the state and ticks of the last status published
        self._thread_error = ThreadError("the ground station's pump failed")
        self.pump_cycles = 0
        self.server = self._listen(host, port, explicit)
        self.host = host
        self.loopback = is_loopback(host)
        self._stop = threading.Event()
        self._closed = False
        # The first cycle before serving: a run directory's info (its mode, columns, limits) is known by
        # the time the URL is printed, so a client that asks at once gets it (on a busy machine the pump's
        # first pass came after such a request, which got an empty answer). A first read that fails (a file
        # that is no run's telemetry) stops the server it bound: its socket is not left to the collector.
        try:
            self._cycle()
            self.server.start()
        except BaseException:
            self.server.stop()
            raise
        self._pump_thread = threading.Thread(target=self._pump, name="gcs-pump", daemon=True)
        self._pump_thread.start()

    @classmethod
    def live(
        cls,
        *,
        bind: str | None = None,
        token: str | None = None,
        commands: bool = True,
        limits: HttpLimits = LIMITS,
        server_class: ServerClass = GcsServer,
    ) -> GroundStation:
        """A station for a run that is about to start: pass :attr:`observer` as ``RunOptions.observer``."""
        uplink = Uplink() if commands else None
        return cls(
            LiveFeed(uplink), bind=bind, token=token, uplink=uplink, limits=limits, server_class=server_class
        )

    @classmethod
    def replay(
        cls,
        run_dir: str | os.PathLike[str],
        *,
        bind: str | None = None,
        token: str | None = None,
        follow: bool = True,
    ) -> GroundStation:
        """A station showing a run directory (following it while another process writes it)."""
        return cls(RunDirSource(Path(run_dir), follow=follow), bind=bind, token=token)

    @classmethod
    def compare(
        cls,
        run_dirs: list[str | os.PathLike[str]],
        *,
        bind: str | None = None,
        token: str | None = None,
        follow: bool = True,
    ) -> GroundStation:
        """A station comparing run directories: the first replayed, the others drawn over its plots
        (:mod:`hil.gcs.compare`)."""
        return cls(CompareSource(run_dirs, follow=follow), bind=bind, token=token)

    def _listen(self, host: str, port: int, explicit: bool) -> Server:
        tries = 1 if explicit or port == 0 else PORT_TRIES
        for attempt in range(tries):
            try:
                return self.server_class(
                    host,
                    port + attempt,
                    self.token,
                    self.hub,
                    self.uplink,
                    lambda: self.info,
                    self.stats,
                    self.limits,
                )
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE and attempt + 1 < tries:
                    continue
                raise LinkError(
                    f"the ground station cannot listen on {host}:{port + attempt}: {exc.strerror or exc}"
                ) from exc
        raise AssertionError("unreachable")

    # ------------------------------------------------------------------ what users see
    @property
    def observer(self) -> LiveFeed:
        """The run observer of a live station (``RunOptions.observer``)."""
        if not isinstance(self.source, LiveFeed):
            raise TypeError("only a live ground station observes a run")
        return self.source

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        """The page's address with the token, as printed at start."""
        return f"http://{url_host(self.host)}:{self.port}/?token={self.token}"

    def stats(self) -> dict[str, Any]:
        """Counters: the hub's (bytes sent, streams, trimmed history), the server's (requests, rejections),
        the feed's drops, the uplink's, the pump's cycles."""
        out: dict[str, Any] = {
            "hub": asdict(self.hub.stats),
            "server": self.server.counters(),
            "pump_cycles": self.pump_cycles,
        }
        feed = self.source
        if isinstance(feed, LiveFeed):
            out["feed"] = asdict(feed.stats)
        if isinstance(feed, CompareSource):
            out["compare"] = feed.counters()
            feed = feed.primary
        if isinstance(feed, RunDirSource):
            out["run_dir"] = {
                "rows": feed.rows,
                "events": feed.events,
                "bad_rows": feed.bad_rows,
                "bad_events": feed.bad_events,
                "finished": feed.finished,
                "stopped": feed.stopped,
                "state": feed.status.get("state"),
                "error": feed.status.get("error"),  # a file refused (a FIFO, unreadable): which, and why
            }
        if self.uplink is not None:
            out["uplink"] = asdict(self.uplink.stats)
        return out

    @property
    def error(self) -> BaseException | None:
        """The pump thread's error, if it had one (the page stopped updating)."""
        return self._thread_error.error

    def check(self) -> None:
        """Raise the pump thread's error, if it had one."""
        self._thread_error.check()

    # ------------------------------------------------------------------ the pump
    def _pump(self) -> None:
        period = 1.0 / PUMP_HZ
        start = time.monotonic()
        k = 0
        try:
            while not self._stop.is_set():
                self._cycle()
                k += 1
                delay = start + k * period - time.monotonic()
                if delay < 0:  # fell behind (a busy machine): skip the missed cycles, never burst
                    k += int(-delay // period) + 1
                    delay = start + k * period - time.monotonic()
                self._stop.wait(max(delay, 0.0))
            self._cycle()  # what came in while stopping
        except Exception as exc:  # stored, raised by check(), shown in the page: never silent
            logger.exception("ground station pump failed")
            self._thread_error.store(exc)
            self.hub.publish(sse("status", dumps({"state": "error", "error": repr(exc)})))

    def _cycle(self) -> None:
        batch = self.source.poll()
        self.pump_cycles += 1
        if batch.new_run:  # the host's next run on a live station: the last run's history is not its
            self.info = None
            self._said = (None, None)
            self.hub.new_run()
        if batch.info is not None:
            self.info = batch.info
            self.hub.set_info(sse("info", dumps(batch.info)))
        chunk = encode_batch(batch)
        if chunk:
            self.hub.publish(chunk, progress=self._progress(batch))

    def _progress(self, batch: Batch) -> bool:
        """Whether ``batch`` holds the run's own progress — what it made (rows, events, link figures, runs
        compared), or a status whose state or ``ticks`` moved — not only a counter of the server's (a
        refused request), which moves while a run's control thread hangs: the hub tells a page that
        (re)connects how old the run's progress is (:func:`hil.gcs.hub.caught_up`)."""
        made = batch.rows or batch.events or batch.link or batch.overlays or batch.overlay_rows
        status = batch.status
        if status is None:
            return bool(made)
        said, self._said = self._said, (status.get("state"), status.get("ticks"))
        # a followed run directory said ``stopped`` (its writer gone): the reader's verdict that nothing
        # more comes, not the run's progress — the newest row is as old as it was (the page: isProgress)
        return bool(made) or (self._said != said and self._said[0] != STOPPED)

    # ------------------------------------------------------------------ closing
    def close(self, linger_s: float = LINGER_S) -> None:
        """Stop the pump (after a last cycle), let the open streams send what they have left (up to
        ``linger_s``), then stop the server. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._pump_thread.join(timeout=5.0)
        self.hub.close()
        end = time.monotonic() + linger_s
        while self.hub.stats.streams_open and time.monotonic() < end:
            time.sleep(0.02)
        self.server.stop()

    def __enter__(self) -> GroundStation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
