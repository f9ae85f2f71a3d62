"""Runs compared: two or more run directories on one page (``hil gcs RUN_A RUN_B ...``).

The first run is the page's own — its timeline, 3D view, panels, alarms and events, as in a replay — and
every other one is an *overlay*: its telemetry drawn on the same plots, on the first run's time axis, with
a legend by run name. The downlink (:mod:`hil.gcs.wire`) carries an overlay as an ``overlay`` message (its
index, name and columns: what the page needs to hold its rows) and ``overlay_rows`` messages; its events and
link statistics are not sent (the page shows the first run's).

Overlays are read once the first run has described itself, so the page never gets an overlay's rows
before the run they are drawn over. An overlay's own state — ``following``, ``finished``, ``read``, or
``error`` with why (a telemetry that is no run's, a directory replaced under the page) — and its damaged
lines go out in the ``status`` message as ``overlays`` (by run name) whenever one changes: an overlay that
cannot be drawn, or stopped being followed, is said, never just missing from the plots. An overlay whose
read is refused (one of its files made a FIFO, or unreadable) is that overlay's ``error``
(:meth:`~hil.gcs.rundir.RunDirSource.fail`): it stopped the station's pump, the first run's page with it.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from hil.gcs.rundir import RunDirSource
from hil.gcs.wire import Batch
from protocol.errors import HilError, InputFormatError


class CompareSource:
    """The page's source for ``run_dirs`` (at least two; each a run directory, followed while it is written
    when ``follow``). :class:`~protocol.errors.InputFormatError` naming the directory that is not one, or
    when fewer than two are given or one is given twice."""

    def __init__(self, run_dirs: list[str | os.PathLike[str]], follow: bool = True) -> None:
        paths = [Path(d) for d in run_dirs]
        if len(paths) < 2:
            raise InputFormatError("comparing needs at least two run directories", "hil gcs")
        for p in paths:
            # Each checked as a replay checks its one directory, before resolve(), which raises
            # RuntimeError for a symlink loop (Python 3.11), a traceback where the answer is this line.
            if not p.is_dir():
                raise InputFormatError("not a directory", str(p))
        try:
            resolved = [p.resolve() for p in paths]
        except (OSError, RuntimeError) as exc:  # a loop or a removal between the check and here
            raise InputFormatError(f"cannot resolve the path ({exc})", "hil gcs") from None
        if len(set(resolved)) != len(resolved):
            raise InputFormatError("a run directory is given twice", "hil gcs")
        self.sources = [
            RunDirSource(p, follow=follow, events_refused_stops=k > 0)  # an overlay's events are not shown
            for k, p in enumerate(paths)
        ]
        self.names = [p.name for p in resolved]
        self._described: set[int] = set()
        self._primary_described = False
        self._overlay_status: dict[str, dict[str, Any]] = {}  # each overlay's newest status, by name

    @property
    def primary(self) -> RunDirSource:
        return self.sources[0]

    def poll(self) -> Batch:
        batch = self.primary.poll()
        if batch.info is not None:
            batch.info["compare"] = list(self.names)
            self._primary_described = True
        if not self._primary_described:
            return batch
        told = False
        for k, source in enumerate(self.sources[1:], start=1):
            try:
                part = source.poll()
            except HilError as exc:  # this run alone: marked in error, the first run and the others go on
                part = source.fail(exc)
            if part.status is not None:
                self._overlay_status[self.names[k]] = part.status
                told = True
            if part.info is not None:
                batch.overlays.append(
                    {
                        "run": k,
                        "name": self.names[k],
                        "columns": part.info["columns"],
                        "note": part.info["note"],
                    }
                )
                self._described.add(k)
            if part.rows:
                batch.overlay_rows.append((k, part.rows))
        if told or (batch.status is not None and self._overlay_status):
            batch.status = {**(batch.status or self.primary.status), "overlays": dict(self._overlay_status)}
        return batch

    def counters(self) -> dict[str, Any]:
        """Each run's rows, damaged lines, whether it finished, and its state (with the error, if any), by
        name."""
        return {
            name: {
                "rows": s.rows,
                "bad_rows": s.bad_rows,
                "finished": s.finished,
                "state": s.status.get("state"),
                "error": s.status.get("error"),
            }
            for name, s in zip(self.names, self.sources, strict=True)
        }
