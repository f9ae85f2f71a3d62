"""What counts as a number in what a user or another program wrote (a JSON document, a TOML file, a
request of the ground station's page): one rule, for every reader that takes a number from one."""

from __future__ import annotations

import math

MAX_SEED = 2**63 - 1
"""The largest seed any command or file takes (``hil montecarlo --seed``, ``hil calibrate bench --seed``,
a scenario's ``[scenario] seed``), each refused beyond it in one wording, ``must be an integer in
0..MAX_SEED``: one bound, kept in one place (a scenario file once took ``seed = 18446744073709551616``,
which the command line refused)."""


def finite_number(value: object) -> float | None:
    """``value`` as a float if it is a finite number as JSON and TOML have them, else None. Not a bool
    (``True == 1`` to Python: ``true`` once read as 1.0 rad/s), not NaN or an infinity, and not an integer
    beyond a float's range: JSON's integers have no bound (``json.loads`` gives a Python int of up to 4300
    digits), and ``float`` or ``math.isfinite`` of one past ±1.8e308 raises OverflowError — which, for an
    event's time of 400 digits, was a traceback where a dropped line was due."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def is_finite_number(value: object) -> bool:
    """Whether ``value`` is a finite number (:func:`finite_number`)."""
    return finite_number(value) is not None
