"""What a run recorded, kept for checks made afterwards (:mod:`hil.runtime.invariants`): a run observer
(:class:`RunRecorder`) that keeps every event, a compact copy of every telemetry row, the summary, and —
with the in-process board — the board's own record of the pulses it put on its pins, each frame with the
protocol state it started in.

Rows keep only what the checks read (:data:`RECORDED`, the board columns tested for emptiness, the rotor
speeds), as arrays once the run is over; a run without a run directory hands its rows over in memory
(``RunOptions(rows_to_observer=True)``). The pulse frames are read from the board once per control tick
and checked as they come (a frame that drives a rotor above its safe width while the board is not ARMED
is a violation: :attr:`RunRecorder.unsafe_frames`), so nothing grows with the run but the rows.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.link.transports.in_process import InProcessBoard
from hil.runtime.observer import RunStart
from hil.runtime.telemetry import board_columns
from protocol.messages import BoardState

RECORDED = ("t", "phase", "board_link", "tel_age_ms", "phone_age_ms", "board_state")
MAX_EXAMPLES = 5  # violations of one kind described in full; more are counted


class RunRecorder:
    """A run observer keeping what the run recorded (see the module docstring); ``n_units`` sizes the
    board columns. Its arrays (:meth:`rows`) are ready once the run has finished."""

    def __init__(self, n_units: int) -> None:
        self.n_units = n_units
        self.board_cols = tuple(board_columns(n_units))
        self.rotor_cols = tuple(f"rotor_speed_{i}" for i in range(n_units))
        self.row_columns = tuple(dict.fromkeys(RECORDED + self.board_cols + self.rotor_cols))
        self.events: list[dict[str, Any]] = []
        self.summary: dict[str, Any] = {}
        self.start: RunStart | None = None
        self._rows: list[tuple[float, ...]] = []
        self._board_values: list[bool] = []
        self._board: InProcessBoard | None = None
        self._frames_seen = 0
        self.frames_checked = 0
        self.frames_missed = 0
        self.unsafe_frames = 0
        self.unsafe_examples: list[str] = []

    # ------------------------------------------------------------------ observer
    def started(self, start: RunStart) -> None:
        self.start = start
        transport = start.host.client.transport
        self._board = transport if isinstance(transport, InProcessBoard) else None

    def row(self, row: Mapping[str, Any]) -> None:
        values = tuple(_num(row[c]) for c in RECORDED) + tuple(_num(row[c]) for c in self.rotor_cols)
        self._rows.append(values)
        self._board_values.append(any(row[c] is not None for c in self.board_cols))

    def event(self, record: Mapping[str, Any]) -> None:
        self.events.append(dict(record))

    def tick(self, t: float) -> None:
        self._check_pulses()

    def finished(self, summary: Mapping[str, Any]) -> None:
        self._check_pulses()
        self.summary = dict(summary)

    # ------------------------------------------------------------------ the board's pulses
    def _check_pulses(self) -> None:
        """The frames the board started since the last look: none may drive a rotor above its safe width
        unless the board was ARMED when it started."""
        board = self._board
        if board is None:
            return
        record = board.pulse_record(self._frames_seen)
        self._frames_seen = record.total
        self.frames_missed += record.missed
        armed = int(BoardState.ARMED)
        safe = record.rotor_safe_us + 1e-6
        for t, widths, state in record.frames:
            self.frames_checked += 1
            if state == armed or state is None:
                continue
            over = [ch for ch in record.rotor_channels if (widths[ch] or 0.0) > safe]
            if over:
                self.unsafe_frames += 1
                if len(self.unsafe_examples) < MAX_EXAMPLES:
                    name = BoardState(state).name
                    self.unsafe_examples.append(
                        f"frame at t={t:.4f} s: channel {over[0]} at {widths[over[0]]} us while {name}"
                    )

    # ------------------------------------------------------------------ after the run
    @property
    def pulses_recorded(self) -> bool:
        """Whether the board's own pulse record was read (an in-process board)."""
        return self._board is not None

    def rows(self) -> dict[str, NDArray[np.float64]]:
        """Each recorded column as a float array (K,) (NaN where a row had no value), ``rotor_speed``
        (K, n), and ``board_values`` (K,) bool: whether the row carried any board value."""
        names = RECORDED
        a = np.asarray(self._rows, dtype=float).reshape(len(self._rows), len(names) + self.n_units)
        out = {name: a[:, i] for i, name in enumerate(names)}
        out["rotor_speed"] = a[:, len(names) :]
        out["board_values"] = np.asarray(self._board_values, dtype=bool)
        return out

    def first_event(self, kind: str, after: float = -math.inf, **match: Any) -> dict[str, Any] | None:
        """The first event of ``kind`` at or after ``after`` whose fields equal ``match``."""
        for e in self.events:
            if e["kind"] == kind and e["t"] >= after and all(e.get(k) == v for k, v in match.items()):
                return e
        return None


def _num(value: Any) -> float:
    return math.nan if value is None else float(value)


__all__ = ["RECORDED", "RunRecorder"]
