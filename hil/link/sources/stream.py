"""What every live phone receiver shares: a bounded queue that its network thread fills and the runtime's
estimator task drains, counters for everything received and everything dropped, and the network thread's
error stored and raised in the consumer (threads never die silently).

A receiver listens on the network, so anything on that network can send it anything: every message is
decoded through :meth:`PhoneReceiver._decode`, which turns *any* failure of that one message (the
decoder's :class:`~protocol.errors.InputFormatError`, and whatever else hostile input makes a parser
raise, e.g. ``RecursionError`` from ``json.loads(b"[" * 60000)``) into a counted, logged drop. Only the
socket itself failing ends a receiver. Drops are logged at most once per second (with the count since).

A receiver (:class:`PhoneReceiver`) listens on one address; its :attr:`~PhoneReceiver.url` says where a
phone must stream to. Senders (the emulator's simulated phone) implement :class:`PhoneSender`.
:mod:`hil.link.sources` picks both by URL scheme.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Protocol, TypeVar
from urllib.parse import urlsplit

from hil.estimation.sensors import SensorSample
from protocol.errors import InputFormatError, LinkError

logger = logging.getLogger(__name__)

MAX_QUEUE = 200_000  # samples held for the consumer; beyond this the oldest are dropped and counted
LOG_EVERY_S = 1.0  # s: at most one warning about dropped messages this often (the rest are counted)

T = TypeVar("T")


def parse_json(data: bytes, source: str) -> object:
    """``data`` as JSON, or :class:`InputFormatError` naming ``source`` for anything unreadable: bad
    UTF-8 or syntax, nesting too deep for the parser (``RecursionError``), an integer past Python's
    digit limit."""
    try:
        return json.loads(data)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise InputFormatError(f"not JSON ({type(exc).__name__}: {str(exc)[:120]})", source) from None


def split_url(url: str, scheme: str, form: str, default_port: int | None = None) -> tuple[str, int, str]:
    """``(host, port, path)`` of a phone-stream URL of ``scheme``; anything else is a :class:`LinkError`
    saying the expected ``form`` (e.g. ``udp://HOST:PORT``)."""
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:  # not a number, out of range
        port = None
    port = default_port if port is None else port
    if parts.scheme != scheme or not parts.hostname or port is None:
        raise LinkError(f"{url}: a phone stream address must be {form}")
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
    overflow: int = 0  # samples dropped because the consumer did not keep up
    message_gaps: int = 0  # messages lost in transit (where the format numbers them)
    refused_connections: int = 0  # HTTP: connections beyond the cap, closed unanswered
    timeouts: int = 0  # HTTP: connections closed because a request did not arrive in time
    last_error: str = ""
    per_kind: dict[str, int] = field(default_factory=dict)


class PhoneReceiver:
    """The shared half of a receiver: subclasses start a network thread that calls :meth:`_deliver` (or
    :meth:`_reject`) and stores a fatal error in ``_error``; they implement :attr:`url` and :meth:`close`."""

    scheme = ""
    app = ""  # the phone app that streams in this format (for error messages)

    def __init__(self, max_queue: int = MAX_QUEUE, clock: Callable[[], float] = time.monotonic) -> None:
        self.stats = StreamStats()
        self._queue: deque[SensorSample] = deque()
        self._max_queue = max_queue
        self._lock = threading.Lock()
        self._error: BaseException | None = None
        self._clock = clock  # s, monotonic: paces the drop warnings
        self._next_log = -float("inf")
        self._unlogged = 0

    @property
    def url(self) -> str:
        raise NotImplementedError

    def _deliver(self, samples: Iterable[SensorSample], bad: int = 0, ignored: int = 0) -> None:
        """One accepted message's samples (and its counts of bad and ignored entries) into the queue."""
        with self._lock:
            st = self.stats
            st.messages += 1
            st.bad_entries += bad
            st.ignored_entries += ignored
            n = 0
            for s in samples:
                st.per_kind[s.kind.label] = st.per_kind.get(s.kind.label, 0) + 1
                self._queue.append(s)
                n += 1
            st.samples += n
            excess = len(self._queue) - self._max_queue
            for _ in range(max(excess, 0)):
                self._queue.popleft()
            st.overflow += max(excess, 0)

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

    def _reject(self, reason: str) -> None:
        """A message that could not be read at all: counted, remembered, logged (at most once a second,
        saying how many more were dropped since)."""
        with self._lock:
            self.stats.bad_messages += 1
            self.stats.last_error = reason
            now = self._clock()
            if now < self._next_log:
                self._unlogged += 1
                return
            self._next_log = now + LOG_EVERY_S
            unlogged, self._unlogged = self._unlogged, 0
        more = f" (and {unlogged} more dropped since the last warning)" if unlogged else ""
        logger.warning("phone %s: dropped %s%s", self.scheme, reason, more)

    def drain(self) -> list[SensorSample]:
        """Every sample received since the last call, in arrival order; raises the network thread's error."""
        self.check()
        with self._lock:
            out = list(self._queue)
            self._queue.clear()
        return out

    def check(self) -> None:
        if self._error is not None:
            raise LinkError(f"phone receiver on {self.url} failed: {self._error!r}") from self._error

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
