"""Which phone a receiver follows when more than one streams to its port: one — the first heard — never a
merge of two.

A receiver hears whatever is sent to its port. In a lab with several phones on one network, two phones
(two SensaGram apps; two Sensor Logger apps, both stamping Unix ns) can stream to the same port; merged,
their readings reach the estimator as if from one phone — a silently wrong attitude. So every readable
message is attributed to a *sender*, by what its format gives (the receivers say how: SensaGram's datagrams
by their source address and port; Sensor Logger's pushes by their ``deviceId`` and ``sessionId``, or by the
peer's address when they carry neither), and :meth:`SenderTable.hear` decides, message by message:

* **The first sender heard with a reading the host uses is followed**; its messages are the stream.
* **Every other sender's messages are dropped** (:attr:`Decision.OTHER`): counted by the receiver
  (``other_phones``, ``other_phone_messages``, ``other_phone_samples``), logged (each new sender, under a
  rate limit), never merged. A message with no reading the host uses (another sensor only, unusable
  entries) holds nothing to drop (:attr:`Decision.NOTHING`): it is counted as any message's entries are,
  changes nothing of the stream's state (its numbering, its sensors), and makes nobody the followed sender —
  an app streaming only a light sensor does not capture the port.
* **The followed sender gone silent hands over.** When it has not been heard for :meth:`SenderTable.bound_s`
  (:data:`SWITCH_AFTER_S`, or :data:`CADENCE_FACTOR` times its own usual spacing when its messages come
  further apart: a long HTTP Push period is not silence), the next sender heard with a usable reading is
  followed instead (:attr:`Decision.SWITCHED`, ``phone_switches``, logged): the app restarted, back from a
  new source port or with a new session. *Unless* that sender streamed alongside a followed one — it sent,
  a followed sender sent after it, and it sent again: then it is another phone, and it is never followed
  (while remembered). So two phones streaming at once, or taking turns, never interleave: the second one's
  messages are dropped whether the followed one is silent or not. To hand the port to another phone, stop
  the followed one's app and start (or restart) the other's.

**Why 2 s.** The host calls the phone stale after ``STALE_AFTER_S`` (0.25 s,
:mod:`hil.runtime.faults`: a phone gap) and starts its estimator afresh, rather than integrate across it,
after a pause of ``MAX_GAP_S`` (1 s, :mod:`hil.runtime.phone_clock`). A sender silent for twice that is, to
the host, already a phone gap whose estimate begins again, so following a new stream then costs the run
nothing it would not pay anyway (the new stream's clock is re-anchored by the host's clock guard, as an
app's restart is); and 2 s is well inside ``RECOVER_WITHIN_S`` (15 s), so a restarted app is followed again
long before the run is lost. A phone streams at 50-500 Hz (a Sensor Logger batch every 20-200 ms), so a
phone that is streaming is never 2 s silent but for a Wi-Fi stall; and a stall does not hand the port to a
phone that was streaming alongside (above).

Nothing here authenticates a phone, and it is not security: any peer can send from any address with any
``deviceId``. It keeps one phone's stream from being merged with another's. Memory stays bounded whatever
arrives: at most :data:`MAX_SENDERS` senders are remembered besides the followed one, the least recently
heard forgotten first (a forgotten sender heard again is new again: counted again, eligible again).

Pure logic, no I/O: the time is passed in (s, any monotonic clock).
"""

from __future__ import annotations

import enum
from collections import OrderedDict, deque
from collections.abc import Hashable
from dataclasses import dataclass

SWITCH_AFTER_S = 2.0
"""s: the followed sender silent this long (at least) lets a new sender be followed (the module docstring)."""
CADENCE_FACTOR = 4.0
"""A sender whose messages come further apart than :data:`SWITCH_AFTER_S` / this (0.5 s: a long HTTP Push
period) is silent only after this many of its usual spacings (the median of its last
:data:`CADENCE_MESSAGES`)."""
CADENCE_MESSAGES = 9
MAX_SENDERS = 256
"""Senders remembered besides the followed one (a lab's phones, with room to spare; a peer spraying source
ports or ``deviceId``\\ s makes the oldest be forgotten, not memory grow)."""


class Decision(enum.Enum):
    """What a message is, for the receiver: the stream's (``FOLLOWED``, ``FIRST``, ``SWITCHED``: deliver
    it), another phone's (``OTHER``: drop it, counted), or not the stream's but with nothing to drop
    (``NOTHING``: count its entries, touch no state of the stream)."""

    FOLLOWED = "followed"  # the followed sender's
    FIRST = "first"  # the first sender heard with a usable reading: followed from now on
    SWITCHED = "switched"  # the followed one was silent: this sender is followed from now on
    OTHER = "other"  # another sender's, with readings the host uses: dropped
    NOTHING = "nothing"  # not the followed sender's, and no reading the host uses in it

    @property
    def streams(self) -> bool:
        """Whether the message is the followed stream's (its samples delivered, its state kept)."""
        return self in (Decision.FOLLOWED, Decision.FIRST, Decision.SWITCHED)


@dataclass(frozen=True, slots=True)
class Heard:
    """:meth:`SenderTable.hear`'s answer: the ``decision``; for ``OTHER``, whether it is the first message
    of that sender dropped (while remembered: ``new``, count and log it as another phone); for
    ``SWITCHED``, the sender followed before (``previous``) and how long it had been silent
    (``silent_s``)."""

    decision: Decision
    new: bool = False
    previous: Hashable | None = None
    silent_s: float = 0.0


@dataclass(slots=True)
class _Seen:
    """A sender not followed: when it was last heard, and under which followed sender (``epoch``, bumped
    at each hand-over) after how many of the followed senders' messages (``seq``)."""

    last_heard: float
    epoch: int
    seq: int
    alongside: bool = False  # it streamed alongside a followed sender: never followed
    dropped: bool = False  # a message of it with readings the host uses was dropped


class SenderTable:
    """The senders one receiver has heard, and the one it follows (the module docstring). Not thread-safe:
    the receiver calls it under its lock."""

    def __init__(self, switch_after_s: float = SWITCH_AFTER_S, max_senders: int = MAX_SENDERS) -> None:
        if switch_after_s <= 0 or max_senders < 1:
            raise ValueError(f"switch_after_s ({switch_after_s}) and max_senders ({max_senders}) must be > 0")
        self.switch_after_s = switch_after_s
        self.max_senders = max_senders
        self.followed: Hashable | None = None
        self._last: float = 0.0  # when the followed sender was last heard
        self._spacings: deque[float] = deque(maxlen=CADENCE_MESSAGES)
        self._seen: OrderedDict[Hashable, _Seen] = OrderedDict()  # least recently heard first
        self._epoch = 0
        self._seq = 0  # messages of followed senders, all of them

    def __len__(self) -> int:
        """Senders remembered, the followed one included."""
        return len(self._seen) + (self.followed is not None)

    def bound_s(self) -> float:
        """How long the followed sender must be silent before another is followed: :data:`SWITCH_AFTER_S`,
        or :data:`CADENCE_FACTOR` times the median of its last spacings when that is longer."""
        if not self._spacings:
            return self.switch_after_s
        usual = sorted(self._spacings)[len(self._spacings) // 2]
        return max(self.switch_after_s, CADENCE_FACTOR * usual)

    def hear(self, sender: Hashable, now: float, usable: bool) -> Heard:
        """One readable message of ``sender`` at ``now`` (s); ``usable``: it holds a reading the host uses."""
        if sender == self.followed:
            self._spacings.append(max(now - self._last, 0.0))
            self._last = now
            self._seq += 1
            return Heard(Decision.FOLLOWED)
        if self.followed is None:
            if not usable:
                return Heard(Decision.NOTHING)
            self._follow(sender, now)
            return Heard(Decision.FIRST)
        seen = self._seen.get(sender)
        if seen is None:
            seen = _Seen(now, self._epoch, self._seq)
            self._remember(sender, seen)
        else:
            self._mark(seen)
            seen.last_heard, seen.epoch, seen.seq = now, self._epoch, self._seq
            self._seen.move_to_end(sender)
        if not usable:
            return Heard(Decision.NOTHING)
        silent = now - self._last
        if seen.alongside or silent <= self.bound_s():
            new, seen.dropped = not seen.dropped, True
            return Heard(Decision.OTHER, new=new)
        previous = self.followed
        for other in self._seen.values():  # the hand-over closes the followed sender's epoch
            self._mark(other)
        del self._seen[sender]
        self._remember(previous, _Seen(self._last, self._epoch, self._seq))
        self._epoch += 1
        self._follow(sender, now)
        return Heard(Decision.SWITCHED, previous=previous, silent_s=silent)

    def _follow(self, sender: Hashable, now: float) -> None:
        self.followed = sender
        self._last = now
        self._spacings.clear()
        self._seq += 1

    def _mark(self, seen: _Seen) -> None:
        """A sender heard under the followed sender now in force, which sent again after it: alongside."""
        if seen.epoch == self._epoch and seen.seq < self._seq:
            seen.alongside = True

    def _remember(self, sender: Hashable, seen: _Seen) -> None:
        self._seen[sender] = seen
        self._seen.move_to_end(sender)
        while len(self._seen) > self.max_senders:
            self._seen.popitem(last=False)  # the least recently heard is forgotten
