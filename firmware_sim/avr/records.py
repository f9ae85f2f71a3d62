"""Reading the harness's record file: pulse edges into pulse frames, PPM trains and resets.

The harness writes one event a line (``firmware/harness/record.c``), times in CPU cycles of harness
time. :class:`RecordReader` reads the file incrementally (it only grows) and turns it into the same
shapes firmware_sim's timeline has (:class:`~firmware_sim.board.timeline.PulseFrame`,
:class:`~firmware_sim.board.timeline.PpmTrain`, :class:`~firmware_sim.board.timeline.ResetEvent`), so the
conformance tests read both targets alike.

A pulse is a rising edge and the falling edge after it on one pin. Its width is measured to the cycle
(1/16 µs) and reported in whole 0.5 µs timer ticks (µs, a multiple of 0.5), the unit the timers put out:
simavr delivers timer events at instruction boundaries, a cycle or two late, so the raw cycle count
jitters by that much while the pin's true width (a whole number of ticks) does not. Every channel
rises at the start of a frame, so the pulses whose rising edges lie within
:data:`FRAME_SKEW_US` of the first one form one frame; a channel without a pulse in it is ``None``.
Pulses that a reset cut short are not pulses an ESC would accept: their frame is dropped and counted
(``truncated``). On the PPM pin a train starts after a gap of at least the PPM sync length.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

from protocol.errors import InputFormatError
from protocol.messages import ResetCause
from protocol.pulse_widths import TICK_US
from protocol.pulses import DEFAULT_PPM

from ..board.timeline import PpmTrain, PulseFrame, ResetEvent

FRAME_SKEW_US = 50.0
"""Rising edges this close to a frame's first one belong to the same frame (timers start together)."""


@dataclass
class _Pending:
    t0: int  # cycle of the frame's first rising edge
    rises: dict[int, int] = field(default_factory=dict)  # pin -> rising cycle
    widths: dict[int, float] = field(default_factory=dict)  # pin -> width µs (completed pulses)


class RecordReader:
    """Incremental parser of one record file. ``n_channels`` pulse pins form frames; ``ppm_pin`` (or
    None) carries the PPM train. Keeps at most ``capacity`` frames and trains (the oldest go)."""

    def __init__(
        self, path: Path, freq_hz: int, n_channels: int, ppm_pin: int | None = None, capacity: int = 20_000
    ) -> None:
        self.path = path
        self.freq = freq_hz
        self.n_channels = n_channels
        self.ppm_pin = ppm_pin
        self.frames: deque[PulseFrame] = deque(maxlen=capacity)
        self._cycles_per_us = freq_hz / 1e6
        self.ppm: deque[PpmTrain] = deque(maxlen=capacity)
        self.resets: list[ResetEvent] = []
        self.brownouts: list[tuple[float, bool]] = []  # (t, held) from 'B' lines
        self.selftest: list[tuple[float, bool]] = []  # (t, pulled low) from 'H' lines
        self.esc_supply: list[tuple[float, bool]] = []  # (t, supply cut) from 'S' lines
        self.watched: list[tuple[float, bytes]] = []  # (t, RAM bytes) from 'M' lines, as they changed
        self.total_frames = 0  # frames closed since the start (the deque keeps the newest ``capacity``)
        self.truncated = 0
        self.marked_cycle = 0  # the file is complete up to this cycle ('T' line)
        self._offset = 0
        self._line = 0
        self._partial = b""
        self._pending: _Pending | None = None
        self._ppm_edges: list[int] = []
        self._ppm_last: int | None = None

    # ------------------------------------------------------------------ reading
    def update(self) -> None:
        """Parse what was appended since the last call."""
        with open(self.path, "rb") as f:
            f.seek(self._offset)
            data = f.read()
        self._offset += len(data)
        data = self._partial + data
        lines = data.split(b"\n")
        self._partial = lines.pop()
        for raw in lines:
            self._line += 1
            self._parse(raw.decode("ascii", "replace"))

    def _parse(self, line: str) -> None:
        parts = line.split()
        if not parts:
            return
        if parts[0] == "M" and len(parts) == 3:  # watched RAM: its bytes in hex
            try:
                self.watched.append((self._seconds(int(parts[1])), bytes.fromhex(parts[2])))
            except ValueError:
                raise InputFormatError(
                    f"unreadable record line {line!r}", str(self.path), self._line
                ) from None
            return
        try:
            kind, cycle, args = parts[0], int(parts[1]), [int(p) for p in parts[2:]]
        except (IndexError, ValueError):
            raise InputFormatError(f"unreadable record line {line!r}", str(self.path), self._line) from None
        if kind == "E" and len(args) == 2:
            self._edge(cycle, args[0], bool(args[1]))
        elif kind == "R" and len(args) == 1:
            self._reset(cycle)
            self.resets.append(ResetEvent(self._seconds(cycle), ResetCause(args[0])))
        elif kind == "B" and len(args) == 1:
            self._reset(cycle)
            self.brownouts.append((self._seconds(cycle), bool(args[0])))
        elif kind == "H" and len(args) == 1:
            self.selftest.append((self._seconds(cycle), bool(args[0])))
        elif kind == "S" and len(args) == 1:
            self.esc_supply.append((self._seconds(cycle), bool(args[0])))
        elif kind == "T":
            self.marked_cycle = cycle
        else:
            raise InputFormatError(f"unknown record line {line!r}", str(self.path), self._line)

    def _seconds(self, cycle: int) -> float:
        return cycle / self.freq

    # ------------------------------------------------------------------ pulses
    def _edge(self, cycle: int, pin: int, high: bool) -> None:
        if pin == self.ppm_pin:
            if high:
                self._ppm_edge(cycle)
            return
        if pin >= self.n_channels:
            return
        p = self._pending
        if high:
            if p is None or (cycle - p.t0) * 1e6 / self.freq > FRAME_SKEW_US:
                self._close_frame()
                p = self._pending = _Pending(cycle)
            p.rises[pin] = cycle
        elif p is not None and pin in p.rises:
            ticks = round((cycle - p.rises[pin]) / (self._cycles_per_us * TICK_US))
            p.widths[pin] = ticks * TICK_US

    def _close_frame(self) -> None:
        p, self._pending = self._pending, None
        if p is None:
            return
        if len(p.widths) != len(p.rises):
            self.truncated += 1  # a pulse still high: cut short (the caller saw no falling edge)
            return
        widths = tuple(p.widths.get(ch) for ch in range(self.n_channels))
        self.frames.append(PulseFrame(self._seconds(p.t0), widths))
        self.total_frames += 1

    def _reset(self, cycle: int) -> None:
        """A reset (or brown-out hold) turns every output off: pulses in flight are cut short."""
        p = self._pending
        if p is not None and len(p.widths) != len(p.rises):
            self._pending = None
            self.truncated += 1
        else:
            self._close_frame()
        self._ppm_edges, self._ppm_last = [], None

    def complete_frames(self) -> list[PulseFrame]:
        """Frames so far, plus the newest one if all its pulses have ended."""
        frames = list(self.frames)
        p = self._pending
        if p is not None and p.rises and len(p.widths) == len(p.rises):
            frames.append(
                PulseFrame(self._seconds(p.t0), tuple(p.widths.get(ch) for ch in range(self.n_channels)))
            )
        return frames

    def newest_complete(self) -> PulseFrame | None:
        """The newest frame whose pulses have all ended (the one in progress if it has), or None."""
        p = self._pending
        if p is not None and p.rises and len(p.widths) == len(p.rises):
            return PulseFrame(self._seconds(p.t0), tuple(p.widths.get(ch) for ch in range(self.n_channels)))
        return self.frames[-1] if self.frames else None

    # ------------------------------------------------------------------ PPM
    def _ppm_edge(self, cycle: int) -> None:
        last = self._ppm_last
        self._ppm_last = cycle
        if last is not None and (cycle - last) * 1e6 / self.freq >= DEFAULT_PPM.min_sync_us:
            edges = self._ppm_edges
            if len(edges) >= 2:
                t0 = edges[0]
                self.ppm.append(PpmTrain(self._seconds(t0), tuple((e - t0) * 1e6 / self.freq for e in edges)))
            self._ppm_edges = []
        self._ppm_edges.append(cycle)
