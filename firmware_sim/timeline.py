"""The inspectable record of what the board's outputs did: pulse frames and resets, in board-clock time.

Each pulse frame is one row ``(t, widths)``: at time ``t`` (s, the board's clock) every channel starts a
pulse of ``widths[ch]`` µs, a whole number of the timers' 0.5 µs ticks (``None``: no pulse on that
channel, e.g. during reset). :meth:`edges`
flattens the rows into ``(t, channel, width_us)`` rising edges. The record is a ring of the last
``capacity`` frames, so memory stays bounded in long runs.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from typing import NamedTuple

from protocol.messages import ResetCause


class PulseEdge(NamedTuple):
    """A pulse on one channel: rising edge at ``t`` (s), ``width_us`` wide."""

    t: float
    channel: int
    width_us: float


class PulseFrame(NamedTuple):
    t: float
    widths: tuple[float | None, ...]


class ResetEvent(NamedTuple):
    """The MCU went into reset at ``t`` (s) for ``cause``; its uptime (``Telemetry.time_ms``) restarts."""

    t: float
    cause: ResetCause


class PpmTrain(NamedTuple):
    """One PPM-sum frame starting at ``t`` (s): ``edges_us`` are the rising-edge offsets within the frame."""

    t: float
    edges_us: tuple[float, ...]


class PulseTimeline:
    """Ring of the last ``capacity`` pulse frames (and PPM trains if enabled)."""

    def __init__(self, capacity: int) -> None:
        self.frames: deque[PulseFrame] = deque(maxlen=capacity)
        self.ppm: deque[PpmTrain] = deque(maxlen=capacity)
        self.total_frames = 0

    def record(self, t: float, widths: tuple[float | None, ...]) -> None:
        self.frames.append(PulseFrame(t, widths))
        self.total_frames += 1

    def edges(self, channel: int | None = None, since: float | None = None) -> list[PulseEdge]:
        """Rising edges, oldest first, optionally of one channel and at or after ``since`` seconds."""
        return list(self._iter_edges(channel, since))

    def _iter_edges(self, channel: int | None, since: float | None) -> Iterator[PulseEdge]:
        for t, widths in self.frames:
            if since is not None and t < since:
                continue
            for ch, w in enumerate(widths):
                if w is not None and (channel is None or ch == channel):
                    yield PulseEdge(t, ch, w)

    def last(self) -> PulseFrame | None:
        return self.frames[-1] if self.frames else None
