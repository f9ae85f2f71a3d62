"""The JSON the project writes — a run's ``summary.json`` and ``events.jsonl``, a replay's ``summary.json`` —
as strict JSON (RFC 8259), which every reader takes: a browser's ``JSON.parse``, jq, pandas.

JSON has no NaN or infinity. Python's :func:`json.dumps` writes them as ``NaN`` and ``Infinity`` unless
told not to, and a file holding one is refused whole by a strict reader: ``hil report`` once called a run's
own summary "damaged" for a final error never measured, and a replay whose truth overlapped none of its
estimates wrote ``"rmse_deg": {"total": NaN, ...}``. A number that is not finite is written as null, as a
figure never measured is."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any


def finite_or_null(value: Any) -> Any:
    """``value`` (a JSON document to write) in JSON's own types: every number that is not finite (NaN,
    ±infinity; numpy's too) as None, numpy scalars and arrays as Python values, tuples as lists, mapping keys
    as strings; anything else JSON has no type for as its number if it is one, else its ``str`` (a path)."""
    if isinstance(value, Mapping):
        return {str(k): finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(v) for v in value]
    if value is None or isinstance(value, (bool, str, int)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    tolist = getattr(value, "tolist", None)  # numpy's scalars and arrays
    if callable(tolist):
        return finite_or_null(tolist())
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    return number if math.isfinite(number) else None


def strict_json(value: Any, indent: int | None = None, compact: bool = False) -> str:
    """``value`` as strict JSON text (:func:`finite_or_null`); one line unless ``indent``, without spaces
    after separators when ``compact`` (the ground station's messages)."""
    separators = (",", ":") if compact else None
    return json.dumps(finite_or_null(value), indent=indent, separators=separators, allow_nan=False)
