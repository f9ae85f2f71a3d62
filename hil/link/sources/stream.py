"""What every live phone receiver shares: a bounded queue that its network thread fills and the runtime's
estimator task drains, counters for everything received and everything dropped, and the network thread's
error stored and raised in the consumer (threads never die silently).

A receiver listens on the network, so anything on that network can send it anything: every message is
decoded through :meth:`PhoneReceiver._decode`, which turns *any* failure of that one message (the
decoder's :class:`~protocol.errors.InputFormatError`, and whatever else hostile input makes a parser
raise, e.g. ``RecursionError`` from ``json.loads(b"[" * 60000)``) into a counted, logged drop. Only the
socket itself failing ends a receiver. Drops are logged at most once per second (with the count since).

**Bounded batches.** Nothing a peer sends can hand the consumer an unbounded batch: :meth:`drain` returns
at most ``max_batch`` samples (:data:`MAX_BATCH`), oldest first, and *holds* the rest for the next call —
a phone's burst (a batch after a Wi-Fi hiccup, a long HTTP Push period) arrives late but whole, spread
over a few estimator ticks. What is held is itself bounded: beyond ``max_queue`` samples
(:data:`MAX_QUEUE`) the *oldest* are dropped, counted (``overflow``) and logged — a flood, or a consumer
that stopped, must not build a backlog that delays the phone's newest readings behind it (the estimator
wants the present: a sample held longer than the queue takes to drain is stale anyway). Both bounds are
checked in the network thread at delivery and in the consumer at the drain, so the consumer's work per
call and the memory held are bounded whatever arrives.

**One phone per receiver.** Several phones may stream to one port (a lab's phones on one network): each
readable message is attributed to its sender and only one sender is followed — the first heard; every other
sender's messages are dropped, counted (``other_phones``, ``other_phone_messages``,
``other_phone_samples``) and logged, never merged; the followed one silent past a bound hands over to a new
sender (``phone_switches``), never to one that streamed alongside it (:mod:`.senders`: the rule and its
bound). Nothing authenticates a phone: this keeps two honest phones apart, it is not security.

**The rule's moments, for the run.** The first phone followed, another phone heard (each new one, under
the log's rate limit; and the first message of another phone after :data:`OTHERS_QUIET_S` without one),
a hand-over, and other phones gone quiet (no other phone's message for :data:`OTHERS_QUIET_S`) are kept as
:class:`~.base.SenderEvent`\\ s in a bounded queue (:data:`MAX_SENDER_EVENTS`, the oldest dropped and
counted: ``unrecorded_sender_events``). The runtime takes them, with a snapshot of the counters, through
:meth:`PhoneReceiver.senders` at its estimator rate, and writes them to ``events.jsonl``: the network
thread never writes a record, and the control thread never waits for it.

A receiver (:class:`PhoneReceiver`) listens on one address; its :attr:`~PhoneReceiver.url` says where a
phone must stream to. Senders (the emulator's simulated phone) implement :class:`PhoneSender`.
:mod:`hil.link.sources.listening` picks both by URL scheme.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol, TypeVar
from urllib.parse import urlsplit

from hil.estimation.sensors import SensorSample
from hil.link.sources.base import SenderEvent, SenderStatus
from hil.link.sources.senders import SWITCH_AFTER_S, Decision, SenderTable
from hil.link.throttle import Throttle
from hil.numbers import finite_number
from hil.threads import ThreadError
from protocol.errors import ConfigError, InputFormatError

logger = logging.getLogger(__name__)

MAX_BATCH = 64
"""Samples handed to the consumer per :meth:`PhoneReceiver.drain`; the rest wait for the next call. A phone
sends ~2 per tick of a 200 Hz estimator (a 20 ms HTTP Push batch: ~9): 64 drains ~30x a phone's rate, and
the host's admission and filter spend a few ms on them (measured: at most 2.4 ms of the control thread
between two control ticks; a 50 000-reading batch in one call took 0.1-0.5 s of it: issue 26)."""
MAX_QUEUE = 4096
"""Samples held for the consumer (~9 s of a 450 Hz phone, drained in 64 calls: 0.3 s at 200 Hz); beyond
this the oldest are dropped and counted (``overflow``)."""
LOG_EVERY_S = 1.0  # s: at most one warning about dropped messages this often (the rest are counted)
NEW_SENDER_LOGS = 8  # new other senders logged one by one per LOG_EVERY_S; beyond, counted in the next line
OTHERS_QUIET_S = 5.0
"""s: no other phone's message for this long and other phones are quiet again (``phone_others_quiet``; the
ground station clears its "another phone" caution). 2.5 x :data:`~.senders.SWITCH_AFTER_S`: a phone
streams every 2-20 ms, a Sensor Logger batch every 20-200 ms, so a phone still streaming is never this
silent but for a Wi-Fi stall; an app stopped is told within 5 s. (A phone pushing less often than this
makes a ``phone_other`` and a ``phone_others_quiet`` per push: two records per 5 s at most.)"""
_TYPE_NAMES = {
    "gyr": "calibrated gyroscope",
    "acc": "calibrated accelerometer",
    "mag": "calibrated magnetometer",
    "total": "total acceleration",
}
MAX_SENDER_EVENTS = 64
"""Moments of the one-phone rule held for the runtime (which takes them 200 times a second: a few at most
are waiting); beyond, the oldest are dropped and counted (``unrecorded_sender_events``)."""

CALIBRATED_QUIET_S = SWITCH_AFTER_S
"""s: a sensor's calibrated type (or Sensor Logger's total acceleration) not heard for this long no longer
holds its sensor: its raw type (uncalibrated; the user acceleration and gravity) is read for it again, and
the change is counted (``calibrated_lapses``) and logged. A phone streaming a type is never this silent
but for a Wi-Fi stall (:data:`~.senders.SWITCH_AFTER_S`'s reasoning), and the host has restarted its
estimate after such a pause anyway, so the two types are never interleaved as one sensor. Without it a user
who turned the calibrated gyroscope off mid-run, keeping the uncalibrated one, had every later gyroscope
reading ignored, counted only among other sensors', and the run lost to "no gyroscope reading came"."""

T = TypeVar("T")


def parse_json(data: bytes, source: str) -> object:
    """``data`` as JSON, or :class:`InputFormatError` naming ``source`` for anything unreadable: bad
    UTF-8 or syntax, nesting too deep for the parser (``RecursionError``), an integer past Python's
    digit limit."""
    try:
        return json.loads(data)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise InputFormatError(f"not JSON ({type(exc).__name__}: {str(exc)[:120]})", source) from None


def reading_number(value: object) -> float | None:
    """One value of a reading as a phone app writes it, as a float: a finite JSON number (the project's one
    rule, :func:`hil.numbers.finite_number`: never a bool) or a string of one (Sensor Logger writes its
    exports' numbers as strings); None for anything else. A ``true`` among a datagram's ``values`` or as a
    push's ``x`` was read as 1.0 — a gyroscope turning at 1 rad/s, used as live."""
    if isinstance(value, str):
        try:
            number = float(value)
        except ValueError:
            return None
        return number if math.isfinite(number) else None
    return finite_number(value)


def split_url(
    url: str,
    scheme: str,
    form: str,
    default_port: int | None = None,
    where: str = "--phone",
    sending: bool = False,
) -> tuple[str, int, str]:
    """``(host, port, path)`` of a phone-stream URL of ``scheme``; anything else is a :class:`ConfigError`
    naming ``where`` (the option that gave it) and saying the expected ``form`` (e.g. ``udp://HOST:PORT``).
    A port that is not a number 0..65535 is refused, naming it (it was replaced by the default port, or
    taken for a missing one). ``sending``: the URL is where a sender sends, so port 0 — "any free port",
    which only a listener can pick — is refused too: every datagram or request to it fails."""
    if any(c.isspace() or not c.isprintable() for c in url):  # urllib drops tabs and line breaks unsaid
        raise ConfigError(f"{url!r}: a space or control character in a phone stream address ({form})", where)
    try:
        parts = urlsplit(url)
    except ValueError as exc:  # an unbalanced "[" or "]": urllib's "Invalid IPv6 URL"
        raise ConfigError(
            f"{url!r}: not a URL ({exc}): a phone stream address must be {form}", where
        ) from None
    try:
        port = parts.port
    except ValueError:  # not a number (also "-1", "+5", " 5"), or out of range
        raw = parts.netloc.rpartition(":")[2]
        raise ConfigError(f"{url!r}: port {raw!r} is not a port number 0..65535 ({form})", where) from None
    port = default_port if port is None else port
    if parts.scheme != scheme or not parts.hostname or port is None:
        raise ConfigError(f"{url!r}: a phone stream address must be {form}", where)
    if sending and port == 0:
        raise ConfigError(
            f"{url!r}: port 0 picks a free port only where hil listens; a phone sends to the port its "
            f"receiver listens on ({form}, PORT 1..65535)",
            where,
        )
    return parts.hostname, port, parts.path or "/"


@dataclass
class StreamStats:
    """What a receiver has seen; nothing it drops goes uncounted. A *message* is one HTTP batch or one UDP
    datagram; an *entry* one sensor reading inside a message."""

    messages: int = 0  # accepted messages
    samples: int = 0  # samples handed to the queue
    bad_messages: int = 0  # unreadable: not JSON, wrong shape, too large, a refused HTTP request
    bad_entries: int = 0  # a reading without finite values or time
    ignored_entries: int = 0  # other sensors (location, light, …)
    overflow: int = 0  # samples dropped, oldest first, beyond max_queue held (a flood, a stalled consumer)
    held: int = 0  # samples waiting for the next drain (at most max_queue): received, drained or dropped
    message_gaps: int = 0  # messages lost in transit (where the format numbers them)
    message_restarts: int = 0  # the numbering started again: it went back, or jumped too far to be losses
    kernel_dropped: int = 0  # UDP: datagrams the kernel dropped, its receive buffer full (SO_RXQ_OVFL)
    refused_connections: int = 0  # HTTP: connections beyond the cap (every slot busy), closed unanswered
    evicted_connections: int = 0  # HTTP: idle connections closed to make room for a new one
    timeouts: int = 0  # HTTP: connections closed because a request did not arrive in time
    not_found: int = 0  # HTTP: requests for another path than the push path, answered 404
    decoder_restarts: int = 0  # HTTP: push decoder processes started again (one died or hung)
    following: str = ""  # the sender followed (:mod:`.senders`): its address, or its app's ids
    phone_switches: int = 0  # the followed sender was silent, and a new one was followed instead
    other_phones: int = 0  # senders heard besides the followed one: their messages dropped (each once)
    other_phone_messages: int = 0  # readable messages of other senders, dropped
    other_phone_samples: int = 0  # the readings the host uses in them, dropped
    unrecorded_sender_events: int = 0  # the rule's moments dropped, MAX_SENDER_EVENTS waiting already
    calibrated_lapses: int = 0  # a calibrated type silent CALIBRATED_QUIET_S: its raw type read again
    held_stale: int = 0  # held before the run started, dropped: older than the stale bound, or a left clock's
    last_error: str = ""
    per_kind: dict[str, int] = field(default_factory=dict)


class PhoneReceiver:
    """The shared half of a receiver: subclasses start a network thread that calls :meth:`_deliver` (or
    :meth:`_reject`) and stores a fatal error in ``_thread_error`` (a :class:`~hil.threads.ThreadError`);
    they implement :attr:`url` and :meth:`close`."""

    scheme = ""
    app = ""  # the phone app that streams in this format (for error messages)

    def __init__(
        self,
        max_queue: int = MAX_QUEUE,
        clock: Callable[[], float] = time.monotonic,
        max_batch: int = MAX_BATCH,
    ) -> None:
        if max_queue < 1 or max_batch < 1:
            raise ValueError(f"max_queue ({max_queue}) and max_batch ({max_batch}) must be at least 1")
        self.stats = StreamStats()
        self._queue: deque[SensorSample] = deque()
        self._max_queue = max_queue
        self._max_batch = max_batch
        self._lock = threading.Lock()
        self._thread_error = ThreadError(lambda: f"phone receiver on {self.url} failed")
        self._clock = clock  # s, monotonic: paces the drop warnings
        self._warnings = Throttle(LOG_EVERY_S)  # drop warnings
        self._senders = SenderTable()
        self._sender_lines = Throttle(LOG_EVERY_S, NEW_SENDER_LOGS)  # new other senders logged
        self._sender_events: deque[SenderEvent] = deque()  # for the runtime (:meth:`senders`)
        self._unrecorded_senders = 0  # new other senders not recorded since the last phone_other
        self._others_streaming = False  # another phone heard within OTHERS_QUIET_S
        self._other_last = 0.0  # when another phone's message was last heard
        # per calibrated type ("gyr", "acc", "mag"; "total": total acceleration): when it was last heard
        self._calibrated_at: dict[str, float] = {}

    @property
    def url(self) -> str:
        raise NotImplementedError

    def _deliver(
        self,
        samples: Sequence[SensorSample],
        bad: int = 0,
        ignored: int = 0,
        per_kind: Mapping[str, int] | None = None,
    ) -> None:
        """One accepted message's samples (and its counts of bad and ignored entries) into the queue; the
        oldest held beyond ``max_queue`` are dropped, counted and logged. ``per_kind``: the message's
        samples per sensor when ``samples`` holds only its newest (a decoder that built no more than the
        queue keeps): the others count as dropped."""
        keep = samples[-self._max_queue :]  # a batch larger than the queue: its oldest go at once
        if per_kind is None:
            per_kind = Counter(s.kind.label for s in samples)
        received = sum(per_kind.values())
        with self._lock:
            st = self.stats
            st.messages += 1
            st.bad_entries += bad
            st.ignored_entries += ignored
            for label, n in per_kind.items():
                st.per_kind[label] = st.per_kind.get(label, 0) + n
            st.samples += received
            self._queue.extend(keep)
            excess = len(self._queue) - self._max_queue
            for _ in range(max(excess, 0)):
                self._queue.popleft()
            dropped = received - len(keep) + max(excess, 0)
            st.overflow += dropped
            st.held = len(self._queue)
        if dropped:
            self._warn(f"{dropped} sample(s), oldest first: more than {self._max_queue} held", dropped)

    def count_overflow(self, n: int) -> None:
        """``n`` samples a consumer took off this receiver to hold, then dropped oldest first beyond
        ``max_queue`` held (:class:`~.listening.ListeningSource` while the run waits for its phone):
        counted in ``overflow`` and logged as the receiver's own drops are."""
        with self._lock:
            self.stats.overflow += n
        self._warn(f"{n} sample(s), oldest first: more than {self._max_queue} held", n)

    def count_held_stale(self, n: int, why: str) -> None:
        """``n`` samples a consumer took off this receiver to hold before its run started, dropped there
        as no present to start from (:meth:`~.listening.ListeningSource.start`; ``why``: what made them
        so, for the log): counted in ``held_stale`` and logged."""
        with self._lock:
            self.stats.held_stale += n
        logger.warning(
            "phone %s: dropped %d reading(s) held while the run waited for its phone and armed the board: %s",
            self.scheme, n, why,
        )  # fmt: skip

    def _attribute(self, sender: Hashable, name: str, usable: int) -> Decision:
        """Whose a readable message is (:mod:`.senders`): ``sender`` as the format identifies it, ``name``
        what to call it in the log, the run's events and ``stats.following``, ``usable`` how many readings
        the host uses it holds. Another phone's message (:attr:`~Decision.OTHER`) is counted here
        (``other_phone_*``) and must not be delivered; one with nothing to drop (:attr:`~Decision.NOTHING`)
        has its entries counted by the caller, and changes no state of the stream; on
        :attr:`~Decision.SWITCHED` the caller starts its per-stream state afresh."""
        line: int | None = None  # a new-sender line is due: how many went unlogged before it
        with self._lock:
            now = self._clock()
            heard = self._senders.hear(sender, now, usable > 0)
            st = self.stats
            decision, previous = heard.decision, st.following
            if decision is Decision.OTHER:
                st.other_phone_messages += 1
                st.other_phone_samples += usable
                st.other_phones += heard.new
                if heard.new:
                    line = self._new_sender_line(now)
                episode = not self._others_streaming  # the first other phone's message after a quiet
                self._others_streaming, self._other_last = True, now
                if line is not None or episode:
                    unrecorded, self._unrecorded_senders = self._unrecorded_senders, 0
                    more = {"not_recorded_before": unrecorded} if unrecorded else {}
                    self._record("phone_other", sender=name, following=st.following, new=heard.new, **more)
                elif heard.new:
                    self._unrecorded_senders += 1
            elif decision in (Decision.FIRST, Decision.SWITCHED):
                st.following = name
                st.phone_switches += decision is Decision.SWITCHED
                if decision is Decision.FIRST:
                    self._record("phone_following", sender=name)
                else:
                    silent = round(heard.silent_s, 3)
                    self._record("phone_switch", sender=name, previous=previous, silent_s=silent)
            following = st.following
        if decision is Decision.FIRST:
            logger.info("phone %s: following %s, the first phone heard", self.scheme, name)
        elif decision is Decision.SWITCHED:
            logger.warning(
                "phone %s: %s silent for %.1f s: following %s from now on (the host restarts its estimate)",
                self.scheme, previous, heard.silent_s, name,
            )  # fmt: skip
        elif line is not None:
            unlogged = f" (and {line} more new senders since the last such warning)" if line else ""
            logger.warning(
                "phone %s: another phone streams to this port, %s: its messages are dropped, never merged "
                "(following %s)%s", self.scheme, name, following, unlogged,
            )  # fmt: skip
        return decision

    def _calibrated_streaming(self) -> frozenset[str]:
        """The calibrated types (``SensorKind.label``s, ``"total"`` for total acceleration) the followed
        stream has sent within :data:`CALIBRATED_QUIET_S`: their sensors' raw types are ignored. One silent
        longer is forgotten — counted (``calibrated_lapses``) and logged: its raw type is read again."""
        lapsed: list[tuple[str, float]] = []
        with self._lock:
            now = self._clock()
            for label, at in list(self._calibrated_at.items()):
                if now - at > CALIBRATED_QUIET_S:
                    del self._calibrated_at[label]
                    self.stats.calibrated_lapses += 1
                    lapsed.append((label, now - at))
            streaming = frozenset(self._calibrated_at)
        for label, silent in lapsed:
            raw = "its user acceleration and gravity are" if label == "total" else "its uncalibrated type is"
            logger.warning(
                "phone %s: no %s reading for %.1f s: %s read for it from now on, if the stream sends them",
                self.scheme, _TYPE_NAMES.get(label, label), silent, raw,
            )  # fmt: skip
        return streaming

    def _calibrated_heard(self, labels: Iterable[str]) -> None:
        """The followed stream sent these calibrated types (:meth:`_calibrated_streaming`) just now."""
        with self._lock:
            now = self._clock()
            for label in labels:
                self._calibrated_at[label] = now

    def _calibrated_forget(self) -> None:
        """A new phone is followed: which calibrated types it sends is its own."""
        with self._lock:
            self._calibrated_at.clear()

    def _new_sender_line(self, now: float) -> int | None:
        """Whether a new other sender is logged — at most :data:`NEW_SENDER_LOGS` lines per
        :data:`LOG_EVERY_S`, the next line saying how many more came meanwhile (a peer spraying source
        ports makes a few lines): None if not, else how many went unlogged before it. Under the lock."""
        return self._sender_lines.due(now)

    def _record(self, kind: str, **fields: object) -> None:
        """A moment of the one-phone rule for the run (:meth:`senders`), with the counters as they are
        now; the oldest dropped and counted beyond :data:`MAX_SENDER_EVENTS`. Under the lock."""
        st = self.stats
        fields.update(
            other_phones=st.other_phones,
            other_phone_messages=st.other_phone_messages,
            other_phone_samples=st.other_phone_samples,
            phone_switches=st.phone_switches,
        )
        if len(self._sender_events) >= MAX_SENDER_EVENTS:
            self._sender_events.popleft()
            st.unrecorded_sender_events += 1
        self._sender_events.append(SenderEvent(kind, fields))

    def senders(self) -> SenderStatus:
        """The one-phone rule as of now, and its moments since the last call (:class:`~.base.SenderStatus`):
        a copy taken under the lock, for the runtime at its estimator rate. Other phones silent for
        :data:`OTHERS_QUIET_S` since one was last heard are quiet again (``phone_others_quiet``, told
        here: the network thread hears nothing when nothing comes)."""
        with self._lock:
            now = self._clock()
            st = self.stats
            if self._others_streaming and now - self._other_last >= OTHERS_QUIET_S:
                self._others_streaming = False
                self._record(
                    "phone_others_quiet", following=st.following, silent_s=round(now - self._other_last, 3)
                )
            events = tuple(self._sender_events)
            self._sender_events.clear()
            return SenderStatus(
                st.following,
                st.phone_switches,
                st.other_phones,
                st.other_phone_messages,
                st.other_phone_samples,
                self._others_streaming,
                events,
            )

    def _decode(self, decode: Callable[[bytes, str], T], data: bytes, source: str) -> tuple[T | None, str]:
        """``(decode(data, source), "")``, or ``(None, reason)`` once the message is counted and logged as
        unreadable: whatever ``decode`` raises costs this one message, never the receiver."""
        try:
            return decode(data, source), ""
        except InputFormatError as exc:
            reason = str(exc)
        except Exception as exc:  # hostile input can make any parser raise (RecursionError, …)
            reason = f"{source}: unreadable ({type(exc).__name__}: {str(exc)[:120]})"
        self._reject(reason)
        return None, reason

    def _kernel_dropped(self, total: int) -> None:
        """The kernel's count of datagrams it dropped on this socket (cumulative, as ``SO_RXQ_OVFL``
        reports it with each datagram): the new ones counted and logged — lost before the receiver saw
        them (the host unscheduled longer than its receive buffer holds), never silently."""
        with self._lock:
            new = total - self.stats.kernel_dropped
            if new <= 0:
                return
            self.stats.kernel_dropped = total
        self._warn(f"{new} datagram(s) in the kernel: its receive buffer was full", new)

    def _reject(self, reason: str) -> None:
        """A message that could not be read at all: counted, remembered, logged (at most once a second,
        saying how many more were dropped since)."""
        with self._lock:
            self.stats.bad_messages += 1
            self.stats.last_error = reason
        self._warn(reason)

    def _warn(self, what: str, count: int = 1) -> None:
        """Log a drop of ``count`` — at most one warning per :data:`LOG_EVERY_S`, the next one saying how
        many were dropped unlogged since (a flood makes a few log lines, not one per message)."""
        with self._lock:
            unlogged = self._warnings.due(self._clock(), count)
        if unlogged is None:
            return
        more = f" (and {unlogged} more dropped since the last warning)" if unlogged else ""
        logger.warning("phone %s: dropped %s%s", self.scheme, what, more)

    def drain(self) -> list[SensorSample]:
        """The oldest samples received and not yet drained, in arrival order: at most ``max_batch``, the
        rest held for the next call (``stats.held``). Raises the network thread's error."""
        self.check()
        with self._lock:
            queue = self._queue
            n = min(len(queue), self._max_batch)
            out = [queue.popleft() for _ in range(n)]
            self.stats.held = len(queue)
        return out

    def check(self) -> None:
        """Raise the network thread's error, if it had one (as every later call does)."""
        self._thread_error.check()

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> PhoneReceiver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PhoneSender(Protocol):
    """Streams samples the way a phone app does. A failed send is counted (``failed``), never raised: a
    phone keeps streaming while the host restarts."""

    url: str
    sent: int  # messages sent
    failed: int  # messages that could not be sent
    batch_s: float  # s: how long the app gathers samples before it sends them (0: each as it comes)

    def send(self, samples: Sequence[SensorSample]) -> bool: ...

    def close(self) -> None: ...
