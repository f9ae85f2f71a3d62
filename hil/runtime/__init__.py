"""The host's runtime: one closed-loop run against a board (:mod:`hil.runtime.loop`) around the host's
estimator and controller (:mod:`hil.runtime.host`).

The names below are imported on first use: importing a module of this package (the command line's
:mod:`hil.runtime.held_signals`, before any command runs) runs this file first, and importing the run
loop here made that import numpy, the host and the board client — ~0.3 s during which a Ctrl-C met
Python's own handler, not hil's (a traceback, and a SIGHUP right after it killed the process)."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hil.runtime.host import Host, TruthSample
    from hil.runtime.loop import ReplayInput, RunOptions, RunResult, check_options, run
    from hil.runtime.phases import Phase
    from hil.runtime.telemetry import RunTrace, telemetry_columns

_LAZY = {
    "Host": "host",
    "TruthSample": "host",
    "ReplayInput": "loop",
    "RunOptions": "loop",
    "RunResult": "loop",
    "check_options": "loop",
    "run": "loop",
    "Phase": "phases",
    "RunTrace": "telemetry",
    "telemetry_columns": "telemetry",
}
"""Each exported name and the module of this package it lives in."""

__all__ = [
    "Host",
    "Phase",
    "ReplayInput",
    "RunOptions",
    "RunResult",
    "RunTrace",
    "TruthSample",
    "check_options",
    "run",
    "telemetry_columns",
]


def __getattr__(name: str) -> object:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
