"""Other phones on the phone's port, as the run records them: a live receiver follows one phone and drops
the others' messages (:mod:`hil.link.sources.senders`); the moments of that rule — the phone followed,
another phone heard, a hand-over, other phones quiet again — become ``events.jsonl`` records, and the
newest counters stay in view for the run's observers (the ground station's phone panel).

The runtime reads the source's :meth:`~hil.link.sources.base.PhoneSource.senders` from its estimator task,
right after the drain, on the control thread: a copy of a few counters and at most
:data:`~hil.link.sources.stream.MAX_SENDER_EVENTS` records, taken under the receiver's lock, never a wait.
A record's ``t`` is the run's time at that read (within one estimator period of the message on the wall
clock; the first ones, heard while the run waited for its phone, at its first estimator tick).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hil.link.sources.base import SenderStatus
    from hil.runtime.runlog import EventLog


class SenderWatch:
    """The run's view of the phones heard on its port: :attr:`status`, the newest
    :class:`~hil.link.sources.base.SenderStatus` (None while the source has none: a recording, a world
    stepped in-process), whose events :meth:`read` writes to ``events.jsonl``."""

    def __init__(self, events: EventLog) -> None:
        self.events = events
        self.status: SenderStatus | None = None

    def read(self, t: float, status: SenderStatus | None) -> None:
        """The source's status at run time ``t`` (s): kept, its events written (``t`` each)."""
        if status is None:
            return
        self.status = status
        for event in status.events:
            self.events.write(t, event.kind, **event.fields)
