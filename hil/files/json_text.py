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

import numpy as np


def finite_or_null(value: Any) -> Any:
    """``value`` (a JSON document to write: mappings, lists and tuples of plain values) with every float that
    is not finite (NaN, ±infinity; numpy's too) as None, numpy scalars and arrays as Python values; the rest
    as it is."""
    if isinstance(value, Mapping):
        return {key: finite_or_null(v) for key, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(v) for v in value]
    if isinstance(value, (np.generic, np.ndarray)):
        return finite_or_null(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def strict_json(value: Any, indent: int | None = None) -> str:
    """``value`` as strict JSON text (:func:`finite_or_null`; anything else JSON has no type for, a path
    say, as its ``str``); one line unless ``indent``."""
    return json.dumps(finite_or_null(value), indent=indent, default=str, allow_nan=False)
