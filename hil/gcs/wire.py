"""The downlink's format: Server-Sent Events whose data is JSON (docs/gcs.md, "Downlink").

One *batch* per pump cycle (~30 per second) becomes one chunk of SSE messages:

``info``    the run: columns, units and their geometry, limits, target, whether commands are taken
``rows``    ``{"rows": [[v, ...], ...]}`` telemetry rows, values in ``info.columns`` order (null: no value)
``events``  ``[{"t": s, "kind": ..., ...}, ...]`` as in ``events.jsonl``
``link``    ``[{"t": s, "frames_in": ..., "bad_frames.crc": ..., ...}, ...]`` link statistics snapshots
``status``  ``{"state": "waiting" | "running" | "ended" | "following" | "stopped" | "finished" | ...}``
            and counters
``overlay``       ``{"run": k, "name": ..., "columns": [...], "note": ...}`` another run compared with
                  this one (:mod:`hil.gcs.compare`)
``overlay_rows``  ``{"run": k, "rows": [[v, ...], ...]}`` that run's telemetry rows, in its columns' order
``caught_up``     ``{"progress_age_s": s}`` the end of the history a stream is sent when it connects, and how
                  long ago the run last made progress (the hub's: :func:`hil.gcs.hub.caught_up`)
``skipped``       ``{"chunks": n}`` this stream fell behind and n chunks were trimmed before it read them:
                  what they held is missing between the rows before and after it (:func:`hil.gcs.hub.skipped`)

JSON has no NaN or infinity: they are sent as null. Floats keep 7 significant digits (time 10), enough for
a display and a third of ``repr``'s bytes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from hil.files.json_text import strict_json

Row = Sequence[Any]


@dataclass
class Batch:
    """What a source has for the page since its last poll."""

    info: dict[str, Any] | None = None
    rows: list[Row] = field(default_factory=list)
    events: list[Mapping[str, Any]] = field(default_factory=list)
    link: list[Mapping[str, Any]] = field(default_factory=list)
    status: dict[str, Any] | None = None
    overlays: list[dict[str, Any]] = field(default_factory=list)  # runs compared: their descriptions
    overlay_rows: list[tuple[int, list[Row]]] = field(default_factory=list)  # (run index, its rows)
    new_run: bool = False
    """What this batch holds is another run's than what came before (a live station kept open for the
    host's next run): the history held is the last run's, not to be resent with this one's ``info``."""

    def __bool__(self) -> bool:
        return bool(
            self.new_run
            or self.info
            or self.rows
            or self.events
            or self.link
            or self.status
            or self.overlays
            or self.overlay_rows
        )


def number(value: Any, digits: int = 7) -> str:
    """One value as JSON text: finite numbers (Python or numpy) compactly, anything else null."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(value)
    try:
        f = float(value)
    except (TypeError, ValueError):
        return "null"
    if not math.isfinite(f):
        return "null"
    if f == int(f) and abs(f) < 1e15:
        return str(int(f))
    return format(f, f".{digits}g")


def encode_rows(rows: Sequence[Row], run: int | None = None) -> str:
    """``{"rows": [[...], ...]}`` with the first column (time) at 10 significant digits (``{"run": k,
    "rows": ...}`` for an overlay's)."""
    parts = []
    for row in rows:
        if not row:
            continue
        cells = [number(row[0], 10)]
        cells += [number(v) for v in row[1:]]
        parts.append("[" + ",".join(cells) + "]")
    head = "{" if run is None else f'{{"run":{int(run)},'
    return head + '"rows":[' + ",".join(parts) + "]}"


def dumps(value: Any) -> str:
    """``value`` as one compact line of strict JSON (:func:`hil.files.json_text.strict_json`)."""
    return strict_json(value, compact=True)


def sse(event: str, data: str) -> bytes:
    """One SSE message (``data`` is single-line JSON)."""
    return f"event: {event}\ndata: {data}\n\n".encode()


def encode_batch(batch: Batch) -> bytes:
    """The batch's SSE messages except ``info`` (which the hub keeps apart), in a fixed order."""
    out = b""
    if batch.rows:
        out += sse("rows", encode_rows(batch.rows))
    if batch.events:
        out += sse("events", dumps(batch.events))
    if batch.link:
        out += sse("link", dumps(batch.link))
    if batch.status is not None:
        out += sse("status", dumps(batch.status))
    for overlay in batch.overlays:
        out += sse("overlay", dumps(overlay))
    for run, rows in batch.overlay_rows:
        out += sse("overlay_rows", encode_rows(rows, run))
    return out
