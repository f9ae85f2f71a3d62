"""A live run's side of the ground station: the run's observer (:mod:`hil.runtime.observer`) on the control
path, and the feed the station's pump drains.

On the control path (every call returns at once): each telemetry row and event goes into a bounded queue
— when the queue is full (the pump thread starved) the item is dropped and counted, never waited for —
with the row's live extras (:data:`hil.gcs.info.LIVE_COLUMNS`: each phone sensor's rate and sample age,
the phone receiver's counts of other phones) read from the host, which costs a few attribute reads. Link
statistics are taken every :data:`LINK_PERIOD_S` of run time. Commands from the page are carried out in
:meth:`LiveFeed.tick` (:class:`hil.gcs.uplink.Uplink`).

A station may be kept open while the host plays one run after another (the same :attr:`GroundStation.observer
<hil.gcs.station.GroundStation.observer>` in each ``RunOptions``): the first thing the next run tells the
feed (an event of its set-up, or :meth:`LiveFeed.started`) begins it afresh — its own description, status,
tick count, phone rates and drop counters — behind a marker in the queue, so that what the last run left
unpolled goes out first, as that run's. Before, the second run's ``info`` was never sent (the page kept the
first run's description over the second run's rows) and its commands were refused as "the run has ended".

On the pump's side: :meth:`LiveFeed.poll` empties the queue into one :class:`~hil.gcs.wire.Batch`. Each
``status`` it sends carries the run's progress (``ticks``, ``tick_t``: counted in :meth:`LiveFeed.tick`),
from which the page judges whether the host is alive — not from the message, which a counter of the
server's (a refused request) also sends while the run's control thread is hung.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil.gcs import info as run_info
from hil.gcs.uplink import Uplink
from hil.gcs.wire import Batch
from hil.runtime.observer import RunStart

if TYPE_CHECKING:
    from hil.runtime.host import Host

logger = logging.getLogger(__name__)

CAPACITY = 8192  # items (rows, events, link snapshots) between two pump cycles; beyond: dropped, counted
HEARTBEAT_S = 0.25  # a run that ticks says so this often (a status with its ticks and the host's clock)
LINK_PERIOD_S = 0.2  # link statistics every this much run time
RATE_WINDOW_S = 1.0  # phone sample rates over this window


@dataclass
class FeedStats:
    rows: int = 0
    events: int = 0
    dropped_rows: int = 0
    dropped_events: int = 0
    dropped_link: int = 0


class _Phone:
    """Each sensor's sample rate over the last second and the age of its newest sample, from the run's
    accepted-sample counters (:attr:`hil.runtime.host.Host.accepted_by_sensor`; host clock: when the count
    last moved). Counts that never go back: a merger's own start from zero when the host starts the
    estimator afresh, taken for counts, drew rates of −600 Hz and a silent sensor's age as 0 ms."""

    def __init__(self) -> None:
        self.labels = run_info.PHONE_LABELS
        self.last_count = dict.fromkeys(self.labels, 0)
        self.last_seen: dict[str, float | None] = dict.fromkeys(self.labels)
        self.window_t: float | None = None
        self.window_count = dict.fromkeys(self.labels, 0)
        self.rates: dict[str, float | None] = dict.fromkeys(self.labels)

    def update(self, t: float, accepted: Mapping[str, int]) -> list[float | None]:
        for k in self.labels:
            n = accepted.get(k, 0)
            if n != self.last_count[k]:
                self.last_count[k] = n
                self.last_seen[k] = t
        if self.window_t is None:
            self.window_t = t
            self.window_count = dict(self.last_count)
        elif t - self.window_t >= RATE_WINDOW_S:
            span = t - self.window_t
            self.rates = {k: (self.last_count[k] - self.window_count[k]) / span for k in self.labels}
            self.window_t, self.window_count = t, dict(self.last_count)
        ages = [None if (s := self.last_seen[k]) is None else (t - s) * 1e3 for k in self.labels]
        return [self.rates[k] for k in self.labels] + ages


class LiveFeed:
    """The run observer of a live ground station (see the module docstring)."""

    def __init__(self, uplink: Uplink | None = None, capacity: int = CAPACITY) -> None:
        self.uplink = uplink
        self.capacity = capacity
        self.stats = FeedStats()
        self._items: deque[tuple[str, Any]] = deque()
        self._host: Host | None = None
        self._phone = _Phone()
        self._next_link = -float("inf")
        self._lock = threading.Lock()  # only for started/finished (rare); the hot path takes none
        self._info: dict[str, Any] | None = None
        self._info_sent = False
        self._status: dict[str, Any] = {"state": "waiting"}
        self._status_changed = True
        self._run_over = False  # finished() came: whatever the observer is told next is another run's
        self._runs_queued = 0  # markers of another run's start in the queue, not yet polled (under the lock)
        self._new_run = False  # the pump's: the next batch is another run's (Batch.new_run)
        self._said: dict[str, Any] = {"state": "waiting"}  # the pump's: the status last sent
        self._columns: list[str] | None = None  # the running host's telemetry columns (rows are queued raw)
        self._counters: dict[str, int] = {}
        self._ticks = 0  # control ticks so far, and the run time of the last: the run's own progress
        self._tick_t: float | None = None
        self._ticks_sent = 0
        self._beat_at = -float("inf")  # when (monotonic) a status last told the ticks
        self.started_at: RunStart | None = None

    # ------------------------------------------------------------------ the control path
    def _next_run(self) -> None:
        """Another run on this feed, after one that finished (control thread): its own description,
        status and counts from now on; a marker in the queue (never dropped) tells :meth:`poll` where the
        last run's items end, so none of them goes out as this run's."""
        with self._lock:
            # what the last run said and the pump has not taken yet (its ``ended`` status) goes out with
            # its items, before the marker
            unsent = (
                None if self._info_sent else self._info,
                dict(self._status) if self._status_changed else None,
            )
            self._run_over = False
            self._host = None
            self._columns = None
            self._info, self._info_sent = None, False
            self._status, self._status_changed = {"state": "waiting"}, True
            self.started_at = None
            self._runs_queued += 1
        self.stats = FeedStats()
        self._phone = _Phone()
        self._next_link = -float("inf")
        self._ticks, self._tick_t = 0, None
        self._items.append(("run", unsent))

    def started(self, start: RunStart) -> None:
        if self._run_over:
            self._next_run()
        host = start.host
        columns = list(host.columns) + list(run_info.LIVE_COLUMNS)
        description = run_info.info(
            mode="live",
            run=start.run_dir.name if start.run_dir else "",
            columns=columns,
            uplink=self.uplink is not None,
            scenario=host.scenario,
            hold=host.hold,
        )
        description["clock"] = start.mode
        with self._lock:
            self._host = host
            self._columns = list(host.columns)
            self.started_at = start
            self._info = description
            self._status = {"state": "running", "mode": start.mode}
            self._status_changed = True
        if self.uplink is not None:
            self.uplink.open()  # commands from now on: the host that carries them out exists

    def row(self, row: Mapping[str, Any]) -> None:
        if self._run_over:
            self._next_run()
        if len(self._items) >= self.capacity:
            self.stats.dropped_rows += 1
            return
        self.stats.rows += 1
        self._items.append(("row", (row, self._extras(row), self._columns)))

    def event(self, record: Mapping[str, Any]) -> None:
        if self._run_over:  # the next run's first word (its set-up's events come before started())
            self._next_run()
        if len(self._items) >= self.capacity:
            self.stats.dropped_events += 1
            return
        self.stats.events += 1
        self._items.append(("event", record))

    def tick(self, t: float) -> None:
        host = self._host
        if host is None:
            return
        self._ticks += 1
        self._tick_t = t
        if self.uplink is not None:
            self.uplink.service(host, t)
        if t >= self._next_link:
            self._next_link = t + LINK_PERIOD_S
            if len(self._items) >= self.capacity:
                self.stats.dropped_link += 1
            else:
                self._items.append(("link", (t, host.client.stats())))

    def ending(self, t: float) -> None:
        """The run's loop has ended at ``t``: the uplink takes no more commands, and logs what came after
        its last tick (:meth:`Uplink.close`), before the run's summary is written."""
        if self.uplink is not None and self._host is not None:
            self.uplink.close(self._host, t)

    def finished(self, summary: Mapping[str, Any]) -> None:
        """The run is over (``summary.json`` written): the status says ``ended`` with its exit and
        summary — also for a run that failed to start (its board never opened), which has no ``info``:
        the hub delivers statuses to readers without one (:meth:`hil.gcs.hub.Hub._read`), so the page
        says the run failed to start and why. The uplink refuses everything from now on."""
        if self.uplink is not None:
            self.uplink.seal()
        with self._lock:
            self._status = {"state": "ended", "exit": summary.get("exit"), "summary": dict(summary)}
            self._status_changed = True
            self._run_over = True

    def _extras(self, row: Mapping[str, Any]) -> list[Any]:
        """The :data:`~hil.gcs.info.LIVE_COLUMNS` values now (None where not known)."""
        host = self._host
        t = row.get("t")
        if host is None or t is None:
            return [None] * len(run_info.LIVE_COLUMNS)
        senders = host.senders.status  # the receiver's counters as the runtime last read them
        if senders is None:
            counts: list[int | None] = [None] * len(run_info.SENDER_COLUMNS)
        else:
            counts = [senders.other_phones, senders.other_phone_messages, senders.phone_switches]
        return [*self._phone.update(t, host.accepted_by_sensor), *counts]

    # ------------------------------------------------------------------ the pump's side
    def poll(self) -> Batch:
        """Everything queued since the last poll — up to the start of another run (:meth:`_next_run`): the
        last run's items and its unsent status in this batch, the next run's from the next one on
        (:attr:`Batch.new_run <hil.gcs.wire.Batch.new_run>`)."""
        batch = Batch(new_run=self._new_run)
        self._new_run = False
        with self._lock:
            current = self._runs_queued == 0  # no other run's start queued: the description is this run's
            if current and self._info is not None and not self._info_sent:
                batch.info, self._info_sent = self._info, True
            if current and self._status_changed:
                batch.status, self._status_changed = dict(self._status), False
        items = self._items
        for _ in range(len(items)):
            kind, payload = items.popleft()
            if kind == "row":
                row, extras, columns = payload
                batch.rows.append([row.get(c) for c in (columns or list(row))] + extras)
            elif kind == "event":
                batch.events.append(payload)
            elif kind == "link":
                t, stats = payload
                batch.link.append({"t": t, **stats.as_dict()})
            else:  # "run": what came before was the last run's; the next batch is the next run's
                info, status = payload
                batch.info = batch.info or info
                batch.status = status or batch.status
                with self._lock:
                    self._runs_queued -= 1
                self._new_run = True
                break
        if batch.status is not None:
            self._said = batch.status
        counters = {
            "feed_dropped_rows": self.stats.dropped_rows,
            "feed_dropped_events": self.stats.dropped_events,  # the page says each kind it did not get
            "feed_dropped_link": self.stats.dropped_link,
            "uplink_rejected": 0 if self.uplink is None else self.uplink.stats.rejected,
        }
        ticks, now = self._ticks, time.monotonic()
        # A ticking run's status goes out every HEARTBEAT_S even while rows flow: its ``host_time`` is how
        # the page tells a feed that comes late (every message, seconds after the host made it: a starved
        # pump, a browser that reads behind) from a live one. Before, a status went out with rows only when
        # a counter changed, and carried no clock: such a page said "receiving" of data seconds old.
        beat = ticks != self._ticks_sent and now - self._beat_at >= HEARTBEAT_S
        if batch.status is not None or counters != self._counters or beat:
            self._counters = counters
            # Every status says how far the run has got (``ticks``, ``tick_t``), and the page counts a
            # status as the run's progress only if ``ticks`` moved: a status sent because a counter of the
            # server's changed (a refused request: ``uplink_rejected``) says nothing of the run, whose
            # control thread may be hung, and must not keep a frozen page "receiving".
            # ``host_time``: the host's monotonic clock (s) at this poll, which the page sets its own clock
            # against with each stream's ``caught_up`` (:func:`hil.gcs.hub.caught_up`): the feed's lag
            progress = {"ticks": ticks, "tick_t": self._tick_t, "host_time": round(now, 3)}
            batch.status = {**(batch.status or self._said), **counters, **progress}
            self._ticks_sent, self._beat_at = ticks, now
        return batch
