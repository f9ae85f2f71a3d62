"""The one shape of a phone source, whatever feeds it: what the runtime asks of the phone of a run.

A run takes its phone samples from one of several places — a phone streaming live (SensaGram's UDP
datagrams, Sensor Logger's HTTP Push), a recorded log played on the run's clock, the simulated phone of the
in-process board's world — and each used to reach the runtime in its own shape (a receiver drained without
a time, a recording drained with one, a world advanced by the scheduler). Here they share one:
:class:`PhoneSource`, built from a URL by :func:`hil.link.sources.create_source` with a
:class:`SourceContext`, so the runtime builds, drives, reports and closes every source the same way and a
user's source (a new app, a file format played live, a rig's own sensors) plugs in without touching it.

A source's methods run on the runtime's control thread (the estimator and control tasks, and the tasks
the source asks for); a source with a thread of its own keeps that thread's error and raises it from
:meth:`PhoneSource.drain`.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from hil.estimation.sensors import SensorLog, SensorSample
    from hil.link.transports import Transport
    from hil.scenario import Scenario
    from hil.timing.clock import Clock
    from hil.timing.scheduler import PeriodicTask

Array = NDArray[np.float64]


@dataclass(frozen=True)
class GroundTruth:
    """What really happened at one instant, as only a simulation or a recording with motion capture knows:
    attitude ``R`` (3, 3) body → ENU and body rate ``omega`` (3,) rad/s."""

    R: Array
    omega: Array


@dataclass(frozen=True)
class SenderEvent:
    """A moment of a live receiver's one-phone rule (:mod:`hil.link.sources.senders`) for the run's
    ``events.jsonl``: its ``kind`` and its ``fields`` (docs/formats.md, "One phone per receiver")."""

    kind: str
    fields: Mapping[str, Any]


@dataclass(frozen=True)
class SenderStatus:
    """A live receiver's one-phone rule as of one read: the sender followed (its address, or its app's
    ids; "" before one), the counters of ``summary.json``'s ``phone`` section, whether another phone is
    streaming (one was heard within :data:`hil.link.sources.stream.OTHERS_QUIET_S`), and the
    :class:`SenderEvent`\\ s since the last read, oldest first."""

    following: str = ""
    phone_switches: int = 0
    other_phones: int = 0
    other_phone_messages: int = 0
    other_phone_samples: int = 0
    others_streaming: bool = False
    events: tuple[SenderEvent, ...] = ()


class EventWriter(Protocol):
    """Writes one record to the run's ``events.jsonl``: clock time ``t`` (s), its ``kind`` and its fields
    (:meth:`hil.runtime.runlog.EventLog.write`)."""

    def __call__(self, t: float, kind: str, **fields: Any) -> None: ...


@dataclass(frozen=True)
class SourceContext:
    """What a source may need of its run beyond its URL.

    ``scenario``: what the run simulates (the world's phone, the control rate); ``clock``: the run's clock
    (a :class:`~hil.timing.clock.LockstepClock` moves only when the runtime moves it); ``lockstep``: whether
    it is one; ``board``: the transport the board client talks over (an in-process board carries the
    simulated world); ``write_event``: a record into ``events.jsonl``, held in time order by the runtime
    until the board's handshake is written; ``recording``: the log ``hil replay`` plays, None otherwise."""

    scenario: Scenario
    clock: Clock
    lockstep: bool
    board: Transport
    write_event: EventWriter
    recording: SensorLog | None = None


SourceFactory = Callable[[str, SourceContext], "PhoneSource"]
"""What a registered scheme resolves to: it takes the source's URL and the run's context and returns the
source, open (listening, playing or stepping)."""


class PhoneSource(abc.ABC):
    """A run's phone: the samples that arrived by now, the truth if known, and its own bookkeeping.

    Every source implements :meth:`drain`, :meth:`truth` and :meth:`close`; the other methods have the
    behaviour of a source that streams until the run stops it and needs nothing more (a live phone), and a
    source that does more (a recording that ends, a world stepped with the board) overrides them.
    ``url`` says where the samples come from (in ``events.jsonl`` and ``summary.json``)."""

    url: str

    @abc.abstractmethod
    def drain(self, now: float) -> list[SensorSample]:
        """The samples that reached the host by clock time ``now`` (s) and were not handed out yet, oldest
        first; a source may hold back part of a burst for the next call (a bounded batch)."""

    @abc.abstractmethod
    def truth(self, now: float) -> GroundTruth | None:
        """The true attitude and rate at clock time ``now`` (s); None when the source cannot know it (a
        live phone) or not then (outside a recording's truth, a motion-capture occlusion)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release what the source holds (sockets, threads, processes); called once, at the run's end."""

    @property
    def rate_hz(self) -> float | None:
        """The fastest sensor's rate (Hz) when the source knows it better than the scenario's phone (a
        recording's own median rate): the estimator task runs at it. None: the scenario's."""
        return None

    def wait_ready(self, wait_s: float, keep_alive: Callable[[], None]) -> None:  # noqa: B027 (ready at once)
        """Return once the first samples can be drained, before the board is armed (its link watchdog is
        fed by ``keep_alive``, called every few ms meanwhile), or raise within ``wait_s`` (s, wall clock)
        saying where the samples were expected. A source that has its samples from the start (a
        recording, a simulated world) is ready at once: nothing to wait for."""

    def tasks(self) -> list[PeriodicTask]:
        """Tasks the source needs on the run's scheduler beside the estimator and control (a simulated
        world stepped every plant step), run first among those due together; none for a source whose
        samples arrive on their own."""
        return []

    def advance(self, now: float) -> None:  # noqa: B027 (nothing to bring forward)
        """Bring the source to clock time ``now`` (s); the control task calls it before it services the
        board, so that the board's telemetry is of the present (a simulated world, whose units the board
        drives). A source whose samples arrive on their own has nothing to bring forward."""

    def start(self, origin: float) -> float | None:
        """The run's slew clock starts at ``origin`` (s), the board armed. Returns the clock time (s) at
        which the run ends because the source does (a recording: the control tick after its last sample),
        or None for a source that streams until the run stops it."""
        return None

    @property
    def exhausted(self) -> bool:
        """True once the source has handed out everything it will ever have (a recording played to its
        end): the run is finished. A stream is never exhausted."""
        return False

    def senders(self) -> SenderStatus | None:
        """The phones heard on the source's port (:class:`SenderStatus`), read by the runtime at its
        estimator rate on the control thread: a copy taken under a lock the network thread holds only
        briefly, never a wait. None for a source that hears one phone by construction (a recording, a
        world stepped in-process)."""
        return None

    def report(self) -> dict[str, dict[str, Any]]:
        """What the source counted, by ``summary.json`` section (``phone``: a receiver's counters;
        ``replay``: the samples a recording released), merged into those sections at the run's end."""
        return {}

    def __enter__(self) -> PhoneSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
