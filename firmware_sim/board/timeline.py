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
    """A frame's pulses at ``t`` (s) and the protocol state the board was in when it started them
    (``BoardState`` value; None where the record does not say: the firmware's edges under simavr)."""

    t: float
    widths: tuple[float | None, ...]
    state: int | None = None


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

    def record(self, t: float, widths: tuple[float | None, ...], state: int | None = None) -> None:
        self.frames.append(PulseFrame(t, widths, state))
        self.total_frames += 1

    def since(self, count: int) -> tuple[list[PulseFrame], int]:
        """The frames recorded after the first ``count`` (oldest first) and how many of those the ring
        no longer holds (it keeps the last ``capacity``)."""
        new = self.total_frames - count
        held = min(new, len(self.frames))
        frames = list(self.frames)[len(self.frames) - held :] if held > 0 else []
        return frames, max(new - held, 0)

    def edges(self, channel: int | None = None, since: float | None = None) -> list[PulseEdge]:
        """Rising edges, oldest first, optionally of one channel and at or after ``since`` seconds."""
        return list(self._iter_edges(channel, since))

    def _iter_edges(self, channel: int | None, since: float | None) -> Iterator[PulseEdge]:
        for t, widths, _state in self.frames:
            if since is not None and t < since:
                continue
            for ch, w in enumerate(widths):
                if w is not None and (channel is None or ch == channel):
                    yield PulseEdge(t, ch, w)

    def last(self) -> PulseFrame | None:
        return self.frames[-1] if self.frames else None
