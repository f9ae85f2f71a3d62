"""A control tick's telemetry: the ``telemetry.csv`` columns, the rotation arithmetic a row needs on plain
floats, and the run's in-memory trace from the slew's start (:class:`RunTrace`: what the summary, the live
progress line and a Monte Carlo campaign's metrics are computed from, with no file in between).

The columns are one schema (:class:`TelemetrySchema`) that gives both the header and a row's layout: a row is
given on the control tick by name — a few dozen plain numbers under their blocks' keys, no numpy call per
cell: rotations are handled as row-major 9-tuples (``hil.so3.floats``' layout) — laid out by the schema
in column order and handed to the run's :class:`hil.runtime.runlog.CsvLog`, whose writer thread formats
and writes it off the tick.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.so3.floats import Mat9

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class ColumnBlock:
    """One value of a telemetry row by name: ``key`` (the name the row's values are given under),
    ``names`` (its columns: one for a scalar, several for a vector such as a value per unit), and whether
    it comes from the board's telemetry (``board``: empty in every row whose ``board_link`` is not live)."""

    key: str
    names: tuple[str, ...]
    board: bool = False


def _scalars(*names: str, board: bool = False) -> list[ColumnBlock]:
    """One block per column, keyed by the column's own name."""
    return [ColumnBlock(name, (name,), board) for name in names]


BOARD_EXTRA_COLUMNS = (
    "battery_a",
    "battery_soc",
    "ubec_v",
    "ubec_a",
    "power_state",
    "watchdog",
    "faults",
    "board_mode",
)
"""The rest of the board's latest Telemetry: battery current (A) and charge (%), UBEC volts and amps, power
state, watchdog state, fault bits, control mode (enumerations as their numbers). Empty, as every board
value, when the host's view of the board is not live."""

VIEW_COLUMNS = ("tel_age_ms", "board_link", "phone_age_ms")
"""The host's view: how old the latest board telemetry is (ms, host clock: it grows while none comes),
:class:`hil.runtime.faults.BoardLink` (0 live, 1 stale, 2 link lost), and how old the newest phone sample
is (ms, host clock; empty before the first)."""


class TelemetrySchema:
    """The ``telemetry.csv`` columns for ``n_units`` units (docs/architecture.md, "Run directory") and
    the one way a row is made from its values, so that the header and the values cannot disagree: a row is
    given by name (:meth:`row`: a block's key → its value, or a sequence of as many values as the block
    has columns), laid out in column order here and nowhere else. A block not given is empty (a tick
    without a live board gives no board value). A key that names no block, or a vector of the wrong
    length, is an error (a misspelled key would otherwise empty a column without a word).

    Blocks, in order: time and phase, the estimator's and the pointing errors; the estimated and true
    attitude (``*_r*``: rotation vector, rad) and rate (``*_w*``, rad/s); the torque demand (N m) and the
    singularity measure δ; per unit the gimbal angles (rad), gimbal rates (rad/s), rotor speeds (rad/s)
    and the commanded gimbal rates and rotor speeds; the pulse widths (µs, gimbal and rotor per unit);
    the board's battery, state and link counters; :data:`BOARD_EXTRA_COLUMNS`; :data:`VIEW_COLUMNS`."""

    def __init__(self, n_units: int) -> None:
        self.n_units = n_units
        units = range(n_units)
        blocks = _scalars("t", "phase", "est_err_deg", "rate_err", "point_err_deg", "track_err_deg")
        for q in ("r", "w"):
            for who in ("est", "true"):
                blocks.append(ColumnBlock(f"{who}_{q}", tuple(f"{who}_{q}{axis}" for axis in "xyz")))
        blocks.append(ColumnBlock("tau", tuple(f"tau_{axis}" for axis in "xyz")))
        blocks += _scalars("delta")
        for name in ("gimbal_angle", "gimbal_rate", "rotor_speed"):
            blocks.append(ColumnBlock(name, tuple(f"{name}_{i}" for i in units), board=True))
        for name in ("cmd_gimbal_rate", "cmd_rotor_speed"):
            blocks.append(ColumnBlock(name, tuple(f"{name}_{i}" for i in units)))
        pulses = tuple(f"pulse_{kind}_{i}" for i in units for kind in ("gimbal", "rotor"))
        blocks.append(ColumnBlock("pulse", pulses, board=True))
        board = ("battery_v", "board_state", "link_rx_frames", "link_bad_frames", "link_age_ms")
        blocks += _scalars(*board, *BOARD_EXTRA_COLUMNS, board=True)
        blocks += _scalars(*VIEW_COLUMNS)
        self.blocks = tuple(blocks)
        self.columns = tuple(name for block in self.blocks for name in block.names)
        self.board_columns = tuple(name for block in self.blocks if block.board for name in block.names)
        self._keys = frozenset(block.key for block in self.blocks)
        self._layout = tuple((block.key, len(block.names)) for block in self.blocks)

    def row(self, values: Mapping[str, Any]) -> list[Any]:
        """The row of ``values`` (by block key) in column order, None where a block is not given."""
        if not values.keys() <= self._keys:
            raise KeyError(f"no telemetry column block(s) {sorted(values.keys() - self._keys)}")
        row: list[Any] = []
        for key, width in self._layout:
            value = values.get(key)
            if width == 1:
                row.append(value)
            elif value is None:
                row.extend([None] * width)
            elif len(value) == width:
                row.extend(value)
            else:
                raise ValueError(f"telemetry block {key!r}: {len(value)} values for {width} columns")
        return row


def telemetry_columns(n_units: int) -> list[str]:
    """The telemetry.csv columns for ``n_units`` units (:class:`TelemetrySchema`)."""
    return list(TelemetrySchema(n_units).columns)


def board_columns(n_units: int) -> list[str]:
    """The columns whose values come from the board's telemetry: empty in every row whose ``board_link``
    is not live (:class:`hil.runtime.faults.BoardLink`), never the last values repeated."""
    return list(TelemetrySchema(n_units).board_columns)


# --------------------------------------------------------------------------- rotations as 9-tuples
def angle_between9(a: Mat9, b: Mat9) -> float:
    """The principal angle (rad, [0, π]) of ``aᵀ b`` — the angle between two rotations — by
    ``atan2(|vee(m)|, (tr m − 1)/2)`` as :func:`hil.so3.principal_angle` (accurate at every angle)."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    trace = a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 + a4 * b4 + a5 * b5 + a6 * b6 + a7 * b7 + a8 * b8
    m01 = a0 * b1 + a3 * b4 + a6 * b7
    m10 = a1 * b0 + a4 * b3 + a7 * b6
    m02 = a0 * b2 + a3 * b5 + a6 * b8
    m20 = a2 * b0 + a5 * b3 + a8 * b6
    m12 = a1 * b2 + a4 * b5 + a7 * b8
    m21 = a2 * b1 + a5 * b4 + a8 * b7
    x, y, z = m21 - m12, m02 - m20, m10 - m01
    return math.atan2(0.5 * math.sqrt(x * x + y * y + z * z), 0.5 * (trace - 1.0))


# --------------------------------------------------------------------------- the run's trace
@dataclass
class RunTrace:
    """One value per control tick from the slew's start: ``t`` (s from the slew's start), the pointing
    error to the target ``point_err_deg``, to the moving reference ``track_err_deg``, the estimator's
    attitude error ``est_err_deg`` (NaN without a truth), the largest |gimbal rate| of any unit
    ``gimbal_rate`` (rad/s) and the singularity measure ``delta``. Each a sequence of floats that grows
    with the run — an ``array('d')``: 8 bytes a value, 6 × 8 bytes × 50 Hz, ~2.4 kB per simulated second
    (~8.6 MB an hour). (They were lists of Python floats: ~32 bytes a value with the list's pointer, ~39 MB
    an hour of a 50 Hz run.) Indexed, measured and iterated as lists were; :meth:`arrays` copies them
    (a numpy view of one would stop it growing while the view lives). Kept whole: the plots draw the run's
    every tick."""

    t: array[float] = field(default_factory=lambda: array("d"))
    point_err_deg: array[float] = field(default_factory=lambda: array("d"))
    track_err_deg: array[float] = field(default_factory=lambda: array("d"))
    est_err_deg: array[float] = field(default_factory=lambda: array("d"))
    gimbal_rate: array[float] = field(default_factory=lambda: array("d"))
    delta: array[float] = field(default_factory=lambda: array("d"))

    FIELDS = ("t", "point_err_deg", "track_err_deg", "est_err_deg", "gimbal_rate", "delta")

    def append(
        self, t: float, point: float, track: float, est: float, gimbal_rate: float, delta: float
    ) -> None:
        self.t.append(t)
        self.point_err_deg.append(point)
        self.track_err_deg.append(track)
        self.est_err_deg.append(est)
        self.gimbal_rate.append(gimbal_rate)
        self.delta.append(delta)

    def __len__(self) -> int:
        return len(self.t)

    def arrays(self) -> dict[str, Array]:
        """Every field as a float array (K,): a copy, so the trace may go on growing."""
        return {name: np.array(getattr(self, name), dtype=float) for name in self.FIELDS}

    def figures(
        self, settle_deg: float, gimbal_rate_limit: float, slew_end_s: float | None = None
    ) -> dict[str, Any]:
        """The pointing figures of the run so far ({} before the slew): settle time (s from the slew's
        start after which the pointing error stays ≤ ``settle_deg``; None if it never did, or if the trace
        ends before ``slew_end_s`` — s from the slew's start at which the last slew's reference comes to
        rest on its target, None: not known — : an error that entered the band while the reference still
        moved has not settled, it is passing through, and a run cut there claimed a settle at 16.5 s that
        the whole run left again at 18.7 s; that run's requirement then said met), final and
        peak pointing error (deg), peak gimbal rate (rad/s) and whether it kept within the limit, minimum
        δ — the last three over the ticks with a live board (None without any). A figure never measured is
        None, never NaN: the final error of a run whose last tick had no estimate (the phone's stream
        restarted, the estimator afresh: no pointing error on hardware, where the estimate is all there is)
        was NaN, written into summary.json as ``NaN`` — not JSON, and read by ``hil report`` as damage."""
        tr = self.arrays()
        if not len(tr["t"]):
            return {}
        err = tr["point_err_deg"]
        above = np.nonzero(~(err <= settle_deg))[0]
        settled = len(above) == 0 or above[-1] + 1 < len(err)
        if slew_end_s is not None and tr["t"][-1] < slew_end_s:
            settled = False  # the run ended before its slew did: nothing has settled yet
        settle_s = (float(tr["t"][above[-1] + 1]) if len(above) else 0.0) if settled else None
        peak = _nan_or(np.nanmax, tr["gimbal_rate"])
        return {
            "settle_s": settle_s,
            "final_error_deg": float(err[-1]) if math.isfinite(err[-1]) else None,
            "peak_error_deg": _nan_or(np.max, err),
            "peak_gimbal_rate": peak,
            "min_delta": _nan_or(np.nanmin, tr["delta"]),
            "settled": settle_s is not None,
            "gimbal_rate_within_limit": None if peak is None else bool(peak <= gimbal_rate_limit),
        }


def _nan_or(reduce: Callable[[Array], Any], values: Array) -> float | None:
    """``reduce`` over the values that are not NaN (ticks without a live board have none); None if none."""
    finite = values[~np.isnan(values)]
    return float(reduce(finite)) if finite.size else None
