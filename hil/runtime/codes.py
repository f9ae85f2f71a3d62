"""What the numbers in ``telemetry.csv``'s coded columns mean, written beside it as
``telemetry_codes.json`` so a row can be read without this package (a spreadsheet, another team's tool).

The columns keep their numbers — a CSV of numbers stays one a plotting tool reads as it is, and every
reader of run directories already does — and this table names them, from the same enums the host and the
board use, so it cannot drift from what was written.
"""

from __future__ import annotations

import enum

from hil.runtime.faults import BoardLink
from hil.runtime.phases import Phase
from protocol.messages import BoardState, ControlMode, FaultFlag, PowerState, WatchdogState

CODED_COLUMNS: dict[str, type[enum.IntEnum]] = {
    "phase": Phase,
    "board_state": BoardState,
    "board_link": BoardLink,
    "power_state": PowerState,
    "watchdog": WatchdogState,
    "board_mode": ControlMode,
}
"""Columns holding one code each: column name → the enum whose values they hold."""
FLAG_COLUMNS: dict[str, type[enum.IntFlag]] = {"faults": FaultFlag}
"""Columns holding a sum of bits: column name → the flag enum whose bits they hold."""
CODES_FILE = "telemetry_codes.json"


def code_table() -> dict[str, dict[str, object]]:
    """``{column: {"kind": "code" | "bits", "values": {number: name}}}`` for every coded column (numbers
    as strings: JSON keys), e.g. ``phase``: ``{"0": "WARMUP", "1": "SLEW", ...}``."""
    table: dict[str, dict[str, object]] = {}
    for column, codes in CODED_COLUMNS.items():
        table[column] = {"kind": "code", "values": {str(int(c)): c.name for c in codes}}
    for column, flags in FLAG_COLUMNS.items():
        bits = {str(int(f)): f.name for f in flags if int(f) and f.name}
        table[column] = {"kind": "bits", "values": bits}
    return table
