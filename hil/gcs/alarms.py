"""The ground station's per-channel limits (the ``alarms`` list of the run's ``info``), derived from the
scenario and the board's configuration: what turns a value into an alarm on the page, and the lines the
page draws on its plots.

Each limit is one channel (a telemetry column) against one threshold::

    {"key": "point_err_deg:high", "column": "point_err_deg", "label": "pointing error", "unit": "deg",
     "op": "above", "value": 0.5, "clear": 0.475, "severity": "warning", "phases": [0, 1, 2, 3], "why": "..."}

``op``: ``above`` (value > threshold), ``below`` (value < threshold), ``abs_above`` (|value| >
threshold), ``equals`` (a state code), ``event`` (no threshold: raised by the run's ``raise_on`` event,
cleared by its ``clear_on`` one — the host decides, so a replay shows what the live page showed). An alarm
is raised on the first row past the threshold and cleared on the first row back past ``clear`` (a
hysteresis band of :data:`HYSTERESIS` of the threshold, so a value hovering at its limit does not raise
and clear an alarm per row). ``phases``: the run phases the limit holds in, as an explicit list of
:class:`hil.runtime.phases.Phase` values (the page checks a row only if its ``phase`` is in the list; a row
without a phase is checked): the rotors' minimum speed only in the slew and the hold — not in the warm-up,
which spins them up, nor while the operator's Disarm has the run suspended, its rotors stopping. (It was
``from_phase``, a lower bound: the phase added after the hold, suspended, fell inside it, and an operator's
Disarm raised a rotor-speed alarm on every unit.) The page evaluates them on every row
it receives (``hil/gcs/static/alarms.js``) and sends an acknowledgement as ``POST /api/ack {"alarm": key,
"raised_t": s}`` (:func:`hil.gcs.uplink.parse_ack`, whose key pattern every key here matches).

One alarm is of the run's events rather than a threshold: ``phone_other:streaming``, another phone
streaming to the phone's port (a caution: its messages are dropped, never merged — docs/formats.md, "One
phone per receiver"), raised by ``phone_other`` and cleared by ``phone_others_quiet`` (no other phone's
message for :data:`hil.link.sources.stream.OTHERS_QUIET_S`); its "worst" is the most other phones heard.

The battery and UBEC thresholds are the board's (the emulator's ``firmware_sim.board.config`` defaults,
which the C firmware's configuration block carries too): the host cannot import the board, so they are
repeated here and ``tests/test_gcs_alarms.py`` holds the two equal. A scenario's ``[board] cells`` and
``link_timeout`` are taken from the scenario.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from hil.link.sources.stream import OTHERS_QUIET_S
from hil.runtime import faults as runtime_faults
from hil.runtime.phases import Phase
from hil.scenario import Scenario
from hil.scenario.reader import DEFAULT_LINK_TIMEOUT_S
from protocol.messages import BoardState

HYSTERESIS = 0.05
"""An alarm clears this fraction of its threshold back inside the limit."""

DEFAULT_CELLS = 3  # the board's battery cells when the scenario does not say (firmware_sim BatteryParams)
WARN_V_CELL = 3.50  # V per cell: the board's power state goes WARN below this (PowerThresholds.warn_v_cell)
SHED_V_CELL = 3.30  # V per cell: the board sheds the rotors below this (PowerThresholds.shed_v_cell)
BROWNOUT_V = 4.30  # V on the UBEC rail: the MCU's brown-out detector resets it (PowerThresholds.brownout_v)
BROWNOUT_RELEASE_V = 4.50  # V on the UBEC rail: the MCU leaves reset above this (brownout_release_v)

WARNING = "warning"
CRITICAL = "critical"


def _limit(
    column: str,
    label: str,
    unit: str,
    op: str,
    value: float,
    severity: str,
    why: str,
    *,
    suffix: str,
    phases: Iterable[Phase] = tuple(Phase),
    scale: float | None = None,
) -> dict[str, Any]:
    """One limit, held in ``phases`` (every phase unless told). ``clear``: where a raised alarm clears —
    :data:`HYSTERESIS` of ``|value|`` back inside the limit (a state code clears as soon as the state is
    another). ``scale`` (the channel's units): the band's measure for a threshold that may be zero (a
    scenario's ``min_rotor_speed = 0``), whose own fraction is no band: ``value * (1 ± HYSTERESIS)`` cleared
    an alarm at its threshold (it chattered, raised and cleared row after row), and for a negative
    threshold put the band on the wrong side, outside the limit."""
    band = HYSTERESIS * (abs(value) or abs(scale or 0.0))
    if op == "below":
        clear = value + band
    elif op in ("above", "abs_above"):
        clear = value - band
    else:
        clear = value
    return {
        "key": f"{column}:{suffix}",
        "column": column,
        "label": label,
        "unit": unit,
        "op": op,
        "value": value,
        "clear": clear,
        "severity": severity,
        "phases": sorted(int(p) for p in phases),
        "why": why,
    }


def event_alarms() -> list[dict[str, Any]]:
    """The alarms raised and cleared by the run's events (``op`` ``event``: the module docstring)."""
    return [
        {
            "key": "phone_other:streaming",
            "column": "phone_other_phones",  # the cell it colours (the phone panel's other phones)
            "label": "another phone on the phone's port",
            "unit": "",
            "op": "event",
            "value": None,
            "clear": None,
            "raise_on": "phone_other",
            "clear_on": "phone_others_quiet",
            "severity": WARNING,
            "phases": sorted(int(p) for p in Phase),
            "why": (
                "another phone is streaming to this port: its messages are dropped, never merged (the "
                f"receiver follows one phone); cleared after {OTHERS_QUIET_S:g} s without one"
            ),
        }
    ]


def alarm_limits(scenario: Scenario) -> list[dict[str, Any]]:
    """Every limit the page checks for a run of ``scenario`` (see the module docstring)."""
    lim = scenario.spacecraft.limits
    board = scenario.board_options
    cells = int(board.get("cells", DEFAULT_CELLS))
    link_timeout_ms = float(board.get("link_timeout", DEFAULT_LINK_TIMEOUT_S)) * 1e3
    stale_ms = runtime_faults.STALE_AFTER_S * 1e3
    out = [
        _limit(
            "point_err_deg",
            "pointing error",
            "deg",
            "above",
            scenario.settle_deg,
            WARNING,
            "the pointing requirement (the scenario's settle_deg)",
            suffix="high",
        ),
    ]
    for k in range(scenario.spacecraft.n_units):
        unit = f"unit {k + 1}"
        out += [
            _limit(
                f"gimbal_rate_{k}",
                f"{unit} gimbal rate",
                "rad/s",
                "abs_above",
                lim.max_gimbal_rate,
                WARNING,
                "the gimbal-rate limit",
                suffix="high",
            ),
            _limit(
                f"rotor_speed_{k}",
                f"{unit} rotor speed",
                "rad/s",
                "below",
                lim.min_rotor_speed,
                WARNING,
                "the rotors' minimum speed (in the slew and the hold: they are spun up in the warm-up and "
                "stopped while the operator's Disarm has the run suspended)",
                suffix="low",
                phases=(Phase.SLEW, Phase.HOLD),
                scale=lim.max_rotor_speed,  # a minimum of 0 (allowed): the band a fraction of the range
            ),
            _limit(
                f"rotor_speed_{k}",
                f"{unit} rotor speed",
                "rad/s",
                "above",
                lim.max_rotor_speed,
                CRITICAL,
                "the rotors' maximum speed",
                suffix="high",
            ),
        ]
    out += [
        _limit(
            "battery_v",
            "battery",
            "V",
            "below",
            round(cells * WARN_V_CELL, 3),
            WARNING,
            f"the board's power warning ({cells} cells × {WARN_V_CELL} V)",
            suffix="low",
        ),
        _limit(
            "battery_v",
            "battery",
            "V",
            "below",
            round(cells * SHED_V_CELL, 3),
            CRITICAL,
            f"the board sheds its rotors ({cells} cells × {SHED_V_CELL} V)",
            suffix="shed",
        ),
        _limit(
            "ubec_v",
            "UBEC rail",
            "V",
            "below",
            BROWNOUT_RELEASE_V,
            WARNING,
            "near the MCU's brown-out (its release level)",
            suffix="low",
        ),
        _limit(
            "ubec_v",
            "UBEC rail",
            "V",
            "below",
            BROWNOUT_V,
            CRITICAL,
            "the MCU's brown-out detector level",
            suffix="brownout",
        ),
        _limit(
            "link_age_ms",
            "board: last host frame",
            "ms",
            "above",
            link_timeout_ms,
            CRITICAL,
            "the board's link watchdog (the scenario's link_timeout): it fails safe",
            suffix="high",
        ),
        _limit(
            "tel_age_ms",
            "host: last telemetry",
            "ms",
            "above",
            stale_ms,
            WARNING,
            "the host's stale bound (its telemetry rows leave the board out)",
            suffix="high",
        ),
        _limit(
            "board_state",
            "board state",
            "",
            "equals",
            float(BoardState.FAILSAFE),
            CRITICAL,
            "the board failed safe",
            suffix="failsafe",
        ),
    ]
    return out + event_alarms()
