"""The run as the page needs to draw it (the ``info`` message): columns, the VSCMG units' geometry, the
limits the plots mark and the alarms check (:mod:`hil.gcs.alarms`), the target, and whether the page
may command the run.

The same description comes from a live run's :class:`~hil.scenario.Scenario` and from a run directory's
``scenario.toml`` (a directory without one still replays: the page then draws no units and no limits).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

import numpy as np

from hil import so3
from hil.estimation.sensors import KINDS
from hil.gcs.alarms import alarm_limits
from hil.runtime import faults as runtime_faults
from hil.runtime.phases import Phase
from hil.scenario import Scenario
from protocol.messages import BoardState, ControlMode, FaultFlag, PowerState, WatchdogState

PHONE_LABELS = tuple(k.label for k in KINDS)

SENDER_COLUMNS = ("phone_other_phones", "phone_other_messages", "phone_switches")
"""A live receiver's one-phone rule as of the row (:class:`hil.link.sources.base.SenderStatus`): other
phones heard (their messages dropped), their messages dropped, hand-overs to a new phone; no value when
the run's phone has no receiver (a world stepped in-process, a recording)."""

LIVE_COLUMNS = (
    *(f"phone_rate_{k}" for k in PHONE_LABELS),
    *(f"phone_age_ms_{k}" for k in PHONE_LABELS),
    *SENDER_COLUMNS,
)
"""What a live run adds to telemetry.csv's columns for the page: each phone sensor's sample rate (Hz, over
the last second) and the age of its newest sample (ms, on the host's clock), and the phone receiver's
counts of other phones (:data:`SENDER_COLUMNS`). (The board's power, UBEC, watchdog, faults and mode, the
host-side age of its telemetry and the host's view of the board are telemetry.csv's own columns:
:data:`hil.runtime.telemetry.BOARD_EXTRA_COLUMNS` and ``VIEW_COLUMNS``.)"""

STALE_AFTER_S = runtime_faults.STALE_AFTER_S
"""A phone sample or board telemetry older than this is drawn stale: the host's own bound, by which its
telemetry rows already leave out a board it cannot hear (:mod:`hil.runtime.faults`)."""


def enums() -> dict[str, Any]:
    """Names of the run's phases (telemetry's ``phase``: :class:`hil.runtime.phases.Phase`), the board's
    enumerations and its fault bits, for the page's labels: the page holds none of its own (it once had the
    phases as a list of three, and showed a suspended run's phase as "—")."""
    return {
        "phase": {int(p): p.name for p in Phase},
        "board_state": {int(s): s.name for s in BoardState},
        "board_link": {int(s): s.name for s in runtime_faults.BoardLink},
        "power_state": {int(s): s.name for s in PowerState},
        "watchdog": {int(s): s.name for s in WatchdogState},
        "board_mode": {int(s): s.name for s in ControlMode},
        "faults": {int(f): f.name for f in FaultFlag if f.value and f.name},
    }


def units_of(scenario: Scenario) -> list[dict[str, list[float]]]:
    """Per unit, body frame: gimbal axis ``g``, spin axis ``s0`` and ``t0 = g × s0`` at gimbal angle 0 (so
    ``s(γ) = cos γ s0 + sin γ t0``), pivot position ``p`` (m)."""
    out = []
    for u in scenario.spacecraft.units:
        g, s0 = np.asarray(u.gimbal_axis, float), np.asarray(u.spin_axis, float)
        out.append(
            {"g": g.tolist(), "s0": s0.tolist(), "t0": np.cross(g, s0).tolist(), "p": list(u.position_m)}
        )
    return out


def scenario_info(scenario: Scenario, hold: bool = False) -> dict[str, Any]:
    """The scenario's part of ``info``: units, limits, target (None with ``hold``: the run holds the attitude
    it estimates at the end of its warm-up, known from its ``slew_start`` event)."""
    params = scenario.spacecraft
    lim = params.limits
    return {
        "scenario": scenario.name,
        "description": scenario.description,
        "n_units": params.n_units,
        "units": units_of(scenario),
        "control_rate_hz": scenario.loop.control_rate_hz,
        "limits": {
            "max_gimbal_rate": lim.max_gimbal_rate,
            "min_rotor_speed": lim.min_rotor_speed,
            "max_rotor_speed": lim.max_rotor_speed,
            "nominal_rotor_speed": params.nominal_rotor_speed,
            "settle_deg": scenario.settle_deg,
            "gimbal_angle": None,  # multi-turn gimbals: no angle limit (docs/gcs.md)
        },
        "alarms": alarm_limits(scenario),
        "target_r": None if hold else so3.log(np.asarray(scenario.slew.R_target)).tolist(),
        "max_rate": scenario.slew.max_rate,
        "max_accel": scenario.slew.max_accel,
    }


def units_from_columns(columns: Sequence[str]) -> int:
    """How many units a telemetry header has (its ``gimbal_angle_<i>`` columns)."""
    return sum(1 for c in columns if re.fullmatch(r"gimbal_angle_\d+", c))


def info(
    *,
    mode: str,
    run: str,
    columns: Sequence[str],
    uplink: bool,
    scenario: Scenario | None,
    hold: bool = False,
    note: str = "",
) -> dict[str, Any]:
    """The whole ``info`` message. ``mode``: ``live`` or ``replay``."""
    out: dict[str, Any] = {
        "mode": mode,
        "run": run,
        "columns": list(columns),
        "uplink": uplink,
        "stale_after_s": STALE_AFTER_S,
        "phone": list(PHONE_LABELS),
        "enums": enums(),
        "note": note,
    }
    if scenario is not None:
        out.update(scenario_info(scenario, hold))
    else:
        out.update(n_units=units_from_columns(columns), units=[], limits={}, alarms=[], target_r=None)
    return out
