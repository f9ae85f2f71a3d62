"""The run's hook for tools that watch a run while it happens and command it (the ground station,
:mod:`hil.gcs`): what :class:`RunObserver` is told, and when.

The runtime calls the observer **on the control path**, so each call must return at once (a bounded queue
that drops and counts, never a lock another thread may hold for long, never I/O):

- :meth:`RunObserver.started` once, when the host and the scheduler exist (before the first control tick);
- :meth:`RunObserver.row` with every telemetry row as it is written (``telemetry.csv``'s columns);
- :meth:`RunObserver.event` with every record written to ``events.jsonl`` (``{"t", "kind", ...}``), the
  ones written before :meth:`started` included;
- :meth:`RunObserver.tick` at the start of every control tick, before the host's own: the observer's place
  to act on the run (commands from the ground arrive here, in the control thread, and nowhere else); it
  may raise :class:`RunAborted` to end the run;
- ``ending(t)``, if the observer has it (optional: most do not), once when the run's loop has ended at
  ``t``, before its summary is made: the observer's last moment to write to the run's record (the ground
  station's uplink logs what came after the last tick, and takes nothing more);
- :meth:`RunObserver.finished` once with the summary, after ``summary.json`` is written.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from protocol.errors import HilError

if TYPE_CHECKING:
    from hil.runtime.host import Host
    from hil.timing.scheduler import Scheduler


class RunAborted(HilError):
    """Raised from :meth:`RunObserver.tick` to end the run on purpose (an operator's abort); the run's
    summary then says ``"exit": "aborted: <why>"`` and :func:`hil.runtime.run` returns normally."""


@dataclass(frozen=True)
class RunStart:
    """What an observer may look at during the run: the host (its client, estimate, phase, counters), the
    scheduler (its tasks' statistics), the run directory, and how the run is clocked (``mode``:
    ``lockstep``, ``realtime`` or ``port``)."""

    host: Host
    scheduler: Scheduler
    run_dir: Path | None  # None: a run without a run directory (out_root=None)
    mode: str


class RunObserver(Protocol):
    def started(self, start: RunStart) -> None: ...

    def row(self, row: Mapping[str, Any]) -> None: ...

    def event(self, record: Mapping[str, Any]) -> None: ...

    def tick(self, t: float) -> None: ...

    def finished(self, summary: Mapping[str, Any]) -> None: ...


class Observers:
    """Several observers as one (``RunOptions.observer`` takes one): each is told everything, in the order
    given; a :class:`RunAborted` from any one's :meth:`tick` ends the run."""

    def __init__(self, *observers: RunObserver) -> None:
        self.observers = observers

    def started(self, start: RunStart) -> None:
        for o in self.observers:
            o.started(start)

    def row(self, row: Mapping[str, Any]) -> None:
        for o in self.observers:
            o.row(row)

    def event(self, record: Mapping[str, Any]) -> None:
        for o in self.observers:
            o.event(record)

    def tick(self, t: float) -> None:
        for o in self.observers:
            o.tick(t)

    def ending(self, t: float) -> None:
        for o in self.observers:
            end = getattr(o, "ending", None)
            if end is not None:
                end(t)

    def finished(self, summary: Mapping[str, Any]) -> None:
        for o in self.observers:
            o.finished(summary)
