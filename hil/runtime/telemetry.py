"""A control tick's telemetry: the ``telemetry.csv`` columns, the rotation arithmetic a row needs on plain
floats, and the run's in-memory trace from the slew's start (:class:`RunTrace`: what the summary, the live
progress line and a Monte Carlo campaign's metrics are computed from, with no file in between).

A row is built on the control tick as a flat list of numbers in column order — no dict, no numpy call per
cell: rotations are handled as row-major 9-tuples (``hil.so3.floats``' layout) — and handed to the
run's :class:`hil.runtime.runlog.CsvLog`, whose writer thread formats and writes it off the tick.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.so3.floats import Mat9

Array = NDArray[np.float64]


def telemetry_columns(n_units: int) -> list[str]:
    """The telemetry.csv columns for ``n_units`` units (docs/architecture.md, "Run directory")."""
    cols = ["t", "phase", "est_err_deg", "rate_err", "point_err_deg", "track_err_deg"]
    cols += [f"{who}_{q}{axis}" for q in ("r", "w") for who in ("est", "true") for axis in "xyz"]
    cols += [f"tau_{a}" for a in "xyz"] + ["delta"]
    for name in ("gimbal_angle", "gimbal_rate", "rotor_speed", "cmd_gimbal_rate", "cmd_rotor_speed"):
        cols += [f"{name}_{i}" for i in range(n_units)]
    cols += [f"pulse_{kind}_{i}" for i in range(n_units) for kind in ("gimbal", "rotor")]
    cols += ["battery_v", "board_state", "link_rx_frames", "link_bad_frames", "link_age_ms"]
    cols += list(BOARD_EXTRA_COLUMNS) + list(VIEW_COLUMNS)
    return cols


def board_columns(n_units: int) -> list[str]:
    """The columns whose values come from the board's telemetry: empty in every row whose ``board_link``
    is not live (:class:`hil.runtime.faults.BoardLink`), never the last values repeated."""
    cols = [f"{name}_{i}" for name in ("gimbal_angle", "gimbal_rate", "rotor_speed") for i in range(n_units)]
    cols += [f"pulse_{kind}_{i}" for i in range(n_units) for kind in ("gimbal", "rotor")]
    cols += ["battery_v", "board_state", "link_rx_frames", "link_bad_frames", "link_age_ms"]
    return cols + list(BOARD_EXTRA_COLUMNS)


BOARD_EXTRA_COLUMNS = (
    "battery_a", "battery_soc", "ubec_v", "ubec_a", "power_state", "watchdog", "faults", "board_mode",
)  # fmt: skip
"""The rest of the board's latest Telemetry: battery current (A) and charge (%), UBEC volts and amps, power
state, watchdog state, fault bits, control mode (enumerations as their numbers). Empty, as every board
value, when the host's view of the board is not live."""

VIEW_COLUMNS = ("tel_age_ms", "board_link", "phone_age_ms")
"""The host's view: how old the latest board telemetry is (ms, host clock: it grows while none comes),
:class:`hil.runtime.faults.BoardLink` (0 live, 1 stale, 2 link lost), and how old the newest phone sample
is (ms, host clock; empty before the first)."""


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
    ``gimbal_rate`` (rad/s) and the singularity measure ``delta``. Lists of floats while the run grows
    (a float per tick each: 6 × 8 bytes × 50 Hz, ~2.4 kB per simulated second)."""

    t: list[float] = field(default_factory=list)
    point_err_deg: list[float] = field(default_factory=list)
    track_err_deg: list[float] = field(default_factory=list)
    est_err_deg: list[float] = field(default_factory=list)
    gimbal_rate: list[float] = field(default_factory=list)
    delta: list[float] = field(default_factory=list)

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
        """Every field as a float array (K,)."""
        return {name: np.asarray(getattr(self, name), dtype=float) for name in self.FIELDS}

    def figures(self, settle_deg: float, gimbal_rate_limit: float) -> dict[str, Any]:
        """The pointing figures of the run so far ({} before the slew): settle time (s from the slew's
        start after which the pointing error stays ≤ ``settle_deg``; None if it never did), final and
        peak pointing error (deg), peak gimbal rate (rad/s) and whether it kept within the limit, minimum
        δ — the last three over the ticks with a live board (None without any)."""
        tr = self.arrays()
        if not len(tr["t"]):
            return {}
        err = tr["point_err_deg"]
        above = np.nonzero(~(err <= settle_deg))[0]
        settled = len(above) == 0 or above[-1] + 1 < len(err)
        settle_s = (float(tr["t"][above[-1] + 1]) if len(above) else 0.0) if settled else None
        peak = _nan_or(np.nanmax, tr["gimbal_rate"])
        return {
            "settle_s": settle_s,
            "final_error_deg": float(err[-1]),
            "peak_error_deg": float(np.nanmax(err)),
            "peak_gimbal_rate": peak,
            "min_delta": _nan_or(np.nanmin, tr["delta"]),
            "settled": settle_s is not None,
            "gimbal_rate_within_limit": None if peak is None else bool(peak <= gimbal_rate_limit),
        }


def _nan_or(reduce: Callable[[Array], Any], values: Array) -> float | None:
    """``reduce`` over the values that are not NaN (ticks without a live board have none); None if none."""
    finite = values[~np.isnan(values)]
    return float(reduce(finite)) if finite.size else None
