"""What every live phone receiver shares: a bounded queue that its network thread fills and the runtime's
estimator task drains, counters for everything received and everything dropped, and the network thread's
error stored and raised in the consumer (threads never die silently).

A receiver (:class:`PhoneReceiver`) listens on one address; its :attr:`~PhoneReceiver.url` says where a
phone must stream to. Senders (the emulator's simulated phone) implement :class:`PhoneSender`.
:mod:`hil.link.sources` picks both by URL scheme.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Protocol
from urllib.parse import urlsplit

from hil.estimation.sensors import SensorSample
from protocol.errors import LinkError

MAX_QUEUE = 200_000  # samples held for the consumer; beyond this the oldest are dropped and counted


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
    bad_messages: int = 0  # not JSON, wrong shape, too large
    bad_entries: int = 0  # a reading without finite values or time
    ignored_entries: int = 0  # other sensors (location, light, …)
    overflow: int = 0  # samples dropped because the consumer did not keep up
    message_gaps: int = 0  # messages lost in transit (where the format numbers them)
    last_error: str = ""
    per_kind: dict[str, int] = field(default_factory=dict)


class PhoneReceiver:
    """The shared half of a receiver: subclasses start a network thread that calls :meth:`_deliver` (or
    :meth:`_reject`) and stores a fatal error in ``_error``; they implement :attr:`url` and :meth:`close`."""

    scheme = ""
    app = ""  # the phone app that streams in this format (for error messages)

    def __init__(self, max_queue: int = MAX_QUEUE) -> None:
        self.stats = StreamStats()
        self._queue: deque[SensorSample] = deque()
        self._max_queue = max_queue
        self._lock = threading.Lock()
        self._error: BaseException | None = None

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

    def _reject(self, reason: str) -> None:
        """A message that could not be read at all: counted, remembered."""
        with self._lock:
            self.stats.bad_messages += 1
            self.stats.last_error = reason

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
