"""A phone streaming over the network while the run goes: the ``udp://`` and ``http://`` phone sources.

Each streamed format has a receiving end (the host listens) and a sending end (the emulator's simulated
phone streams to the host exactly as the app would), looked up by URL scheme in :data:`STREAMS`:

=================================  =====================================================================
``udp://HOST:PORT``                SensaGram's JSON datagrams, one per sensor event (:mod:`.phone_udp`)
``http://HOST:PORT[/PATH]``        Sensor Logger's HTTP Push batches (:mod:`.phone_push`)
``HOST:PORT``                      the same as ``udp://HOST:PORT``
=================================  =====================================================================

:class:`ListeningSource` is a receiver in the one shape of a run's phone (:class:`~.base.PhoneSource`);
:func:`listen` is the factory both schemes register under ``vscmg_hil.phone_sources``.
"""

from __future__ import annotations

import importlib
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import asdict
from typing import Any
from urllib.parse import urlsplit

from hil.estimation.admission import PhoneGuard, Verdict
from hil.estimation.sensors import SensorSample
from hil.link.sources.base import GroundTruth, PhoneSource, SenderStatus, SourceContext
from hil.link.sources.stream import MAX_BATCH, MAX_QUEUE, PhoneReceiver, PhoneSender, StreamStats
from hil.scenario.reader import HOST_STALE_AFTER_S
from protocol.errors import ConfigError, LinkTimeout

STREAMS: dict[str, tuple[str, str]] = {
    "udp": ("hil.link.sources.phone_udp:PhoneUdpReceiver", "hil.link.sources.phone_udp:PhoneUdpSender"),
    "http": ("hil.link.sources.phone_push:PhonePushServer", "hil.link.sources.phone_push:PhonePushSender"),
}
"""Streamed format by URL scheme: ``("module:Receiver", "module:Sender")``, each class taking the URL and
imported on first use (the HTTP side brings its guard and decoder process along)."""

POLL_S = 0.02  # s: how often the wait for a first sample looks (and keeps the board's link fed)


def phone_url(address: str, where: str = "--phone") -> str:
    """``address`` as a phone-stream URL: a bare ``HOST:PORT`` becomes ``udp://HOST:PORT``; a scheme that
    is not a streamed format (:data:`STREAMS`) is a :class:`ConfigError` naming ``where``."""
    url = address if "://" in address else f"udp://{address}"
    scheme = urlsplit(url).scheme
    if scheme not in STREAMS:
        raise ConfigError(f"{address!r}: a phone stream is udp://HOST:PORT or http://HOST:PORT/PATH", where)
    return url


def _stream_class(url: str, end: int) -> Any:
    module_name, _, name = STREAMS[urlsplit(url).scheme][end].partition(":")
    return getattr(importlib.import_module(module_name), name)


def open_receiver(address: str) -> PhoneReceiver:
    """Listen for a phone stream at ``address`` (see :func:`phone_url`; port 0 picks a free one); a busy
    or bad address is a :class:`~protocol.errors.LinkError`."""
    url = phone_url(address)
    receiver: PhoneReceiver = _stream_class(url, 0)(url)
    return receiver


def open_sender(address: str) -> PhoneSender:
    """Stream a (simulated) phone to ``address`` the way its app does."""
    url = phone_url(address)
    sender: PhoneSender = _stream_class(url, 1)(url)
    return sender


class ListeningSource(PhoneSource):
    """A receiver as a run's phone: what arrived is drained whatever the clock says (the samples carry the
    phone's own stamps), there is no truth, and the receiver's counters go to ``summary.json``'s
    ``phone`` section."""

    def __init__(self, receiver: PhoneReceiver) -> None:
        self.receiver = receiver
        self.url = receiver.url
        # what the wait for the first samples took off the receiver to judge them: handed over first, in
        # batches of MAX_BATCH, as the receiver would have
        self._waited: deque[SensorSample] = deque()
        self._guard = PhoneGuard()  # the admission policy over what was held before the run (its newest)
        # readings ever held (those dropped beyond MAX_QUEUE included), and of them: how many up to the
        # last one the guard accepted, and how many up to the last one of a clock the stream left
        self._held_total = 0
        self._accepted_through = 0
        self._left_clock_through = 0

    def drain(self, now: float) -> list[SensorSample]:
        waited = self._waited
        if waited:
            return [waited.popleft() for _ in range(min(len(waited), MAX_BATCH))]
        return self.receiver.drain()

    def truth(self, now: float) -> GroundTruth | None:
        return None

    def close(self) -> None:
        self.receiver.close()

    def wait_ready(self, wait_s: float, keep_alive: Callable[[], None]) -> None:
        """The gyroscope's and the accelerometer's first *usable* samples within ``wait_s`` (wall clock):
        without either the estimator cannot start. What arrives is judged by the host's admission policy
        (a :class:`~hil.estimation.admission.PhoneGuard` of its own: a reading every one of whose values
        is 1e160 parses, and is no reading) and kept for the run, which judges it again and counts it.
        Else a :class:`LinkTimeout` saying what was heard (:func:`heard`: readings that came and were all
        refused, with the reasons, are said so) and where to send what is missing."""
        receiver = self.receiver
        admitted: Counter[str] = Counter()
        refused: dict[str, Counter[str]] = {}
        end = time.monotonic() + wait_s
        while time.monotonic() < end:
            receiver.check()
            keep_alive()
            for _ in range(MAX_QUEUE // MAX_BATCH + 1):  # what came since the last look (bounded)
                batch = receiver.drain()
                if not batch:
                    break
                for sample, refusal in zip(batch, self._hold(batch), strict=True):
                    label = sample.kind.label
                    if refusal is not None:
                        refused.setdefault(label, Counter())[refusal] += 1
                    else:
                        admitted[label] += 1
            if all(admitted[kind] for kind in NEEDED):
                return
            time.sleep(POLL_S)
        said = heard(receiver.stats, {k: c for k, c in refused.items() if not admitted[k]})
        raise LinkTimeout(
            f"no phone stream on {self.url} within {wait_s:.0f} s: {said}; start "
            f"`firmware-sim --world SCENARIO --phone {self.url}` (it streams its simulated phone there) or "
            f"point {receiver.app} on a phone at it, its accelerometer and gyroscope on"
        )

    def start(self, origin: float) -> float | None:
        """The run starts, its board armed: of what was held since the wait for the phone began (the wait
        itself, then the arming), the readings stamped more than :data:`HELD_KEEP_S` before the newest
        one the admission policy took are dropped, counted (``held_stale``) and logged. They were handed to
        the run as it started, as if live: a phone whose accelerometer came 3 s after its gyroscope had
        3 s of gyroscope readings taken as the present, their delay shrinking faster than any clock runs
        — two ``phone_jump`` faults of a clock that never jumped, honest readings dropped as ``future``,
        the warm-up restarted. So are the readings of a clock the stream left while they were held (the
        policy re-anchored on a later one: :meth:`_hold`), whatever their stamps: an app restarted during
        the wait had its old clock's readings — stamped *after* the new clock's, so never "old" — handed to
        the run first, as the present, then a ``phone_restart`` and honest readings dropped as ``past``;
        a stray the wait anchored on, 1000 s ahead, reached the estimator as its first reading. A stray
        stamped past the newest that no clock followed is kept: the run's own guard judges it."""
        receiver = self.receiver
        for _ in range(MAX_QUEUE // MAX_BATCH + 1):  # what came while the board was armed (bounded)
            batch = receiver.drain()
            if not batch:
                break
            self._hold(batch)
        waited = self._waited
        # of a clock the stream left: those held up to its last reading, less those dropped beyond MAX_QUEUE
        left = max(self._left_clock_through - (self._held_total - len(waited)), 0)
        if left:
            stamps = [waited.popleft().t_s for _ in range(left)]
            receiver.count_held_stale(
                left,
                f"of a clock the phone left while they were held (its app restarted, its clock stepped, "
                f"or a stray taken for it), stamped {min(stamps):.6g} to {max(stamps):.6g} s; its "
                f"clock is at {self._guard.newest:.6g} s now",
            )
        newest = self._guard.newest
        fresh = deque(s for s in waited if not s.t_s < newest - HELD_KEEP_S)
        if len(fresh) < len(waited):
            oldest = min(s.t_s for s in waited)
            receiver.count_held_stale(
                len(waited) - len(fresh),
                f"stamped up to {newest - oldest:.2f} s before the newest, too old to start from",
            )
            self._waited = fresh
        return None

    def _hold(self, batch: list[SensorSample]) -> list[str | None]:
        """``batch`` judged by the admission policy of what is held before the run (per reading, in
        order: why it was refused, or None if admitted) and held for the run (:meth:`_keep`). A
        re-anchoring verdict (``RESTART``, ``JUMP``, ``STRAY``: the stream's clock moved, or its anchor
        was a stray) marks every reading held up to the last one the policy accepted before it as of a
        clock the stream left (dropped at :meth:`start`); the readings after that one, the run that
        moved the clock among them, are of the new clock."""
        guard = self._guard
        refusals: list[str | None] = []
        for i, sample in enumerate(batch, start=self._held_total + 1):
            verdict = guard.admit(sample)
            if verdict is Verdict.DROP:
                refusals.append(guard.last_reason or "?")
                continue
            if verdict is not Verdict.ACCEPT:
                self._left_clock_through = self._accepted_through
            self._accepted_through = i
            refusals.append(None)
        self._keep(batch)
        return refusals

    def _keep(self, batch: list[SensorSample]) -> None:
        """``batch`` held for the run; beyond :data:`MAX_QUEUE` held the oldest dropped and counted in the
        receiver's ``overflow``, as the receiver itself does (the run wants the present)."""
        waited = self._waited
        waited.extend(batch)
        self._held_total += len(batch)
        excess = len(waited) - MAX_QUEUE
        if excess > 0:
            for _ in range(excess):
                waited.popleft()
            self.receiver.count_overflow(excess)

    def senders(self) -> SenderStatus:
        return self.receiver.senders()

    def report(self) -> dict[str, dict[str, Any]]:
        return {"phone": {"url": self.url, **asdict(self.receiver.stats)}}


NEEDED = ("gyr", "acc")
"""The sensors a run cannot start without (``StreamStats.per_kind``'s labels)."""
HELD_KEEP_S = HOST_STALE_AFTER_S
"""s of the phone's clock: what was held before the run started is kept only this far back from its
newest reading — the age at which the host calls the phone stale: anything older is no present to start
the estimate from."""


def heard(stats: StreamStats, refused: dict[str, Counter[str]] | None = None) -> str:
    """What a receiver heard, for a user whose phone stream did not start: nothing; or messages with no
    reading the host uses (another sensor: an uncalibrated one, a user acceleration without gravity),
    readings it could not use, requests for another path, other phones' messages dropped; or which of
    :data:`NEEDED` never came; ``refused``: per sensor with no reading admitted, the readings the
    admission policy refused, by reason (they came, and none was usable)."""
    if not (stats.messages or stats.bad_messages or stats.not_found or stats.other_phone_messages):
        return "nothing was heard"
    said = []
    if stats.messages:
        kinds = ", ".join(f"{k} {n}" for k, n in stats.per_kind.items()) or "none"
        said.append(f"{stats.messages} messages heard, their readings by sensor: {kinds}")
        missing = [k for k in NEEDED if not stats.per_kind.get(k)]
        if missing:
            said.append(f"no {' and no '.join(_NAMES[k] for k in missing)} among them")
    for label, reasons in (refused or {}).items():
        total = sum(reasons.values())
        why = ", ".join(f"{reason} {n}" for reason, n in reasons.most_common())
        said.append(f"{total} {_NAMES.get(label, label)} readings arrived but every one was refused ({why})")
    if stats.ignored_entries:
        said.append(
            f"{stats.ignored_entries} readings of sensors the host does not use (it takes the calibrated "
            "gyroscope, magnetometer and accelerometer with gravity: Sensor Logger's TotalAcceleration, "
            "or Accelerometer with Gravity; of the uncalibrated types, SensaGram's or Sensor Logger's, "
            "those whose calibrated type is not streamed)"
        )
    if stats.bad_entries:
        said.append(f"{stats.bad_entries} readings without finite values or time")
    if stats.bad_messages:
        said.append(f"{stats.bad_messages} unreadable messages, the last: {stats.last_error}")
    if stats.not_found:
        said.append(f"{stats.not_found} requests for another path than the push path (answered 404)")
    if stats.other_phone_messages:
        said.append(
            f"{stats.other_phone_messages} messages of {stats.other_phones} other phone(s) dropped: the "
            f"receiver follows one phone, {stats.following} (stop the others' apps)"
        )
    return "; ".join(said)


_NAMES = {"gyr": "gyroscope", "acc": "accelerometer", "mag": "magnetometer"}


def listen(url: str, context: SourceContext) -> ListeningSource:
    """The ``udp://`` and ``http://`` source: listen on ``url`` (``events.jsonl`` gets ``phone_listening``
    with the address bound, a port 0 resolved)."""
    source = ListeningSource(open_receiver(url))
    context.write_event(context.clock.now(), "phone_listening", url=source.url)
    return source
