"""The downlink's history and its readers: encoded chunks in order, held up to a byte budget, and a cursor
per browser.

The pump thread publishes one chunk per cycle; each stream (a coroutine on the server's IOLoop, woken
through :meth:`Hub.watch`; or a thread blocking in :meth:`Reader.read`) takes the chunks after its cursor
and writes them all in one go. Nothing here waits on a browser: a slow one falls
behind, and if the chunks it has not read yet are trimmed (the budget is full) it skips to the oldest one
held, the skip counted and the reader told where (:func:`skipped`). A browser that connects late (or
reconnects) gets ``info`` and then the whole history held, so its plots and timeline start from the
beginning of what is held, and then a ``caught_up`` message (:func:`caught_up`): what came before it is
history, resent, not the run's progress now — it says how long ago the run last made progress
(``progress_age_s``, from what the publisher marked as progress), so a page that reconnects to a hung run
says it is stale at once rather than "receiving" its history.

Each read ends with an SSE ``id:`` line naming where the reader is (:meth:`Hub.resume`): a browser's
``EventSource`` sends the last one back when it reconnects (``Last-Event-ID``), and a stream of the same
hub, whose chunks since are still held, takes up there — the chunks it missed, then ``caught_up`` — with
no ``info`` and no history resent: before, every reconnection of every page cost the whole history (up
to the budget, 64 MiB) and the page its store rebuilt, so a flaky link kept a page loading for ever.
"""

from __future__ import annotations

import json
import re
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

DEFAULT_BUDGET = 64 * 1024 * 1024  # bytes of history held for late joiners and the replay's timeline
READ_MAX = 256 * 1024
"""bytes a stream takes from the hub at a time (one chunk larger than this is taken whole). The whole
history in one read was a copy of up to the budget per browser, and the server's write buffer another
until the browser read it: 16 streams that never read held ~2 GiB of a 60 MiB history for
``SEND_TIMEOUT_S``. In slices, each written once the one before it has gone, a browser that does not
read holds one slice."""


_EVENT_ID = re.compile(r"([0-9a-f]{16})\.([0-9]{1,12})\.([0-9]{1,15})")


def caught_up(progress_age_s: float | None, host_time: float | None = None) -> bytes:
    """The message that ends a reader's history: ``{"progress_age_s": s}``, seconds since the run's last
    progress when the reader got there (null: none yet); with ``host_time`` (the host's monotonic clock, s,
    as the stream writes it) too: the page sets its clock against the host's with it, so the ``host_time``
    of each live ``status`` (:meth:`hil.gcs.live.LiveFeed.poll`) tells it how late the feed comes, whatever
    the two clocks' offset (a browser on another machine, through a tunnel)."""
    said: dict[str, float | None] = {
        "progress_age_s": None if progress_age_s is None else round(progress_age_s, 3)
    }
    if host_time is not None:
        said["host_time"] = round(host_time, 3)
    return b"event: caught_up\ndata: " + json.dumps(said).encode() + b"\n\n"


def skipped(chunks: int, history: bool = False) -> bytes:
    """The message a slow reader gets where the chunks it had not read were trimmed before it read them:
    ``{"chunks": n}``, how many it will never get (their rows, events and statuses). Before, the skip was
    counted in ``/api/stats`` only and the page drew on across the hole as if nothing was missing; now it
    says, and where (the page has the rows on either side of it). ``history``: the run's own first chunks,
    trimmed before this reader was given the history (``{"chunks": n, "history": true}``, right after
    ``info``): a page that connected late to a long run (past the budget: ~20 min of a live run's rows)
    drew it from the middle as if that were its start, its first events, commands and alarms missing
    unsaid."""
    said: dict[str, int | bool] = {"chunks": chunks}
    if history:
        said["history"] = True
    return b"event: skipped\ndata: " + json.dumps(said).encode() + b"\n\n"


@dataclass
class HubStats:
    chunks: int = 0  # published
    bytes_published: int = 0
    trimmed_chunks: int = 0  # dropped from the history (budget full)
    skipped_chunks: int = 0  # not delivered to a slow reader because they had been trimmed
    bytes_sent: int = 0  # written to browsers' sockets (downlink)
    streams_opened: int = 0
    streams_open: int = 0
    streams_resumed: int = 0  # taken up where a reconnecting browser left off (no history resent)


class Hub:
    """Chunks numbered from 0; ``budget`` bytes of the newest are held."""

    def __init__(
        self, budget: int = DEFAULT_BUDGET, clock: Callable[[], float] = time.monotonic,
        host_clock: Callable[[], float] | None = None,
    ) -> None:  # fmt: skip
        """``clock``: for the progress's age (s); ``host_clock``: the clock (s) that each :func:`caught_up`
        carries, the one a live feed's statuses carry as ``host_time`` (None: none, no lag told)."""
        self.budget = budget
        self.clock = clock
        self.host_clock = host_clock
        self.ident = secrets.token_hex(8)  # this hub's, in its readers' event ids (another server: another)
        self._progress_at: float | None = None  # when (clock) a chunk marked as progress was published
        self.stats = HubStats()
        self._cond = threading.Condition()
        self._chunks: list[bytes] = []
        self._first = 0  # number of the oldest chunk held
        self._held = 0  # bytes held
        self._info: bytes | None = None
        self._info_version = 0
        self._info_from = 0  # number of the first chunk published after the current info (the run's own)
        self._run_from = 0  # number of the first chunk of the current run (new_run): where a reader starts
        self.closed = False
        self._watchers: list[Callable[[], None]] = []

    def watch(self, on_change: Callable[[], None]) -> None:
        """Call ``on_change()`` (from the publishing thread, outside the hub's lock; it must not block)
        after every publish, new ``info`` and close: how an event loop learns there is something to read
        without a thread waiting on the hub."""
        self._watchers.append(on_change)

    def _changed(self) -> None:
        for on_change in self._watchers:
            on_change()

    # ------------------------------------------------------------------ the pump's side
    def set_info(self, info: bytes) -> None:
        """The ``info`` message every reader gets first (a new one restarts every reader's stream)."""
        with self._cond:
            self._info = info
            self._info_version += 1
            self._info_from = self._first + len(self._chunks)
            self._progress_at = self.clock()
            self._cond.notify_all()
        self._changed()

    def new_run(self) -> None:
        """Another run follows (a live station kept open for the host's next run): the chunks held are the
        last run's, dropped (not counted as trimmed: nobody is told they are missing) with its ``info``, so
        a reader that (re)connects gets this run's history alone once its ``info`` comes — before, the new
        ``info`` came with the whole history again, the last run's rows drawn as the new run's. A reader
        still reading the last run's chunks is told it skipped them (:func:`skipped`)."""
        with self._cond:
            self._first += len(self._chunks)
            self._chunks.clear()
            self._held = 0
            self._info = None
            self._info_from = self._run_from = self._first
            self._progress_at = None
            self._cond.notify_all()
        self._changed()

    def publish(self, chunk: bytes, progress: bool = True) -> None:
        """``chunk`` after the others; ``progress``: it holds the run's own progress (rows, events, link
        figures, a status whose state or ticks moved), not only a counter of the server's."""
        with self._cond:
            if progress:
                self._progress_at = self.clock()
            self._chunks.append(chunk)
            self._held += len(chunk)
            self.stats.chunks += 1
            self.stats.bytes_published += len(chunk)
            if self._held > self.budget and len(self._chunks) > 1:
                # trim to 90 % of the budget in one go (a list slice, not one pop per chunk)
                n, freed = 0, 0
                while n < len(self._chunks) - 1 and self._held - freed > 0.9 * self.budget:
                    freed += len(self._chunks[n])
                    n += 1
                del self._chunks[:n]
                self._held -= freed
                self._first += n
                self.stats.trimmed_chunks += n
            self._cond.notify_all()
        self._changed()

    def close(self) -> None:
        """Wake every reader for the last time."""
        with self._cond:
            self.closed = True
            self._cond.notify_all()
        self._changed()

    # ------------------------------------------------------------------ the readers' side
    def count_sent(self, n: int) -> None:
        with self._cond:
            self.stats.bytes_sent += n

    def count_stream(self, delta: int) -> None:
        with self._cond:
            self.stats.streams_open += delta
            self.stats.streams_opened += max(delta, 0)

    def reader(self) -> Reader:
        return Reader(self)

    def resume(self, reader: Reader, last_event_id: str | None) -> bool:
        """Put a new ``reader`` where a reader of this hub left off: ``last_event_id`` is the last id its
        browser received (the ``Last-Event-ID`` header of a reconnecting ``EventSource``). Only for this
        hub, the same ``info``, and a place whose chunks since are still held; otherwise (False) the
        reader starts afresh, ``info`` and the whole history."""
        match = _EVENT_ID.fullmatch((last_event_id or "").strip())
        if match is None or match[1] != self.ident:
            return False
        version, cursor = int(match[2]), int(match[3])
        with self._cond:
            if self._info is None or version != self._info_version:
                return False
            if not self._first <= cursor <= self._first + len(self._chunks):
                return False
            reader.info_version, reader.cursor = version, cursor
            reader.live_from, reader.caught_up = cursor, False  # no history: caught up at once
            self.stats.streams_resumed += 1
        return True

    def _read(self, reader: Reader, timeout: float, max_bytes: int | None = None) -> bytes | None:
        """What ``reader`` has not had yet (``info`` first; before any ``info``, the chunks published so
        far: a live run's statuses), waiting up to ``timeout`` s for something; b"" if nothing came, None
        when the hub is closed and the reader has everything. ``max_bytes``: whole
        chunks up to about that many (at least one), the rest left for the next read. The read that
        takes the last chunk held when the reader took ``info`` ends with :func:`caught_up`."""
        with self._cond:
            end_wait = self._cond.wait_for(
                lambda: (
                    self.closed
                    or (self._info is not None and reader.info_version != self._info_version)
                    or reader.cursor < self._first + len(self._chunks)
                    or (reader.info_version and not reader.caught_up)
                ),
                timeout,
            )
            if not end_wait:
                return b""
            out = b""
            if self._info is not None and reader.info_version != self._info_version:
                reader.info_version = self._info_version
                reader.cursor = self._first  # a new run description: the whole history again
                reader.live_from = self._first + len(self._chunks)  # the history: the chunks held now
                reader.caught_up = False
                out += self._info
                if self._first > self._info_from:  # the run's first chunks are gone: the reader is told
                    out += skipped(self._first - self._info_from, history=True)
            # No run described yet (a live station whose run has not started): the chunks all the same —
            # its statuses, the last one saying a run that failed to start ended and why; before, such a
            # reader got nothing until an ``info`` that never came, and the page never learnt the run's fate.
            # Once ``info`` comes the reader has the whole history again, after it.
            if reader.cursor < self._first:
                self.stats.skipped_chunks += self._first - reader.cursor
                out += skipped(self._first - reader.cursor)  # the reader is told, before what follows
                reader.cursor = self._first
            start = reader.cursor - self._first
            end = len(self._chunks) if max_bytes is None else self._slice_end(start, max_bytes - len(out))
            chunks = self._chunks[start:end]
            reader.cursor += len(chunks)
            out += b"".join(chunks)
            if reader.info_version and not reader.caught_up and reader.cursor >= reader.live_from:
                reader.caught_up = True
                at = self._progress_at
                host_time = None if self.host_clock is None else self.host_clock()
                out += caught_up(None if at is None else max(self.clock() - at, 0.0), host_time)
            if not out and self.closed:
                return None
            if out:  # where this reader is, for its browser to resume from (resume)
                out += f"id: {self.ident}.{reader.info_version}.{reader.cursor}\n\n".encode()
            return out

    def _slice_end(self, start: int, room: int) -> int:
        """The index after the chunks from ``start`` that fit in ``room`` bytes (at least one chunk)."""
        end, size = start, 0
        while end < len(self._chunks) and (end == start or size + len(self._chunks[end]) <= room):
            size += len(self._chunks[end])
            end += 1
        return end


class Reader:
    """One browser's position in the hub."""

    def __init__(self, hub: Hub) -> None:
        self.hub = hub
        self.cursor = hub._run_from  # the current run's first chunk: the chunks before it are another run's
        self.info_version = 0
        self.live_from = 0  # the number of the first chunk after the history this reader was given
        self.caught_up = False  # whether it was told the history has ended (:func:`caught_up`)

    def read(self, timeout: float, max_bytes: int | None = None) -> bytes | None:
        """What this reader has not had yet, waiting up to ``timeout`` s (0: not at all) for something;
        b"" if nothing came, None once the hub is closed and everything was read. ``max_bytes``: at most
        about that much (whole chunks, at least one; :data:`READ_MAX`), the rest on the next reads."""
        return self.hub._read(self, timeout, max_bytes)
