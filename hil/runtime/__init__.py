"""The host's runtime: one closed-loop run against a board (:mod:`hil.runtime.loop`) around the host's
estimator and controller (:mod:`hil.runtime.host`)."""

from hil.runtime.host import Host, TruthSample
from hil.runtime.loop import ReplayInput, RunOptions, RunResult, check_options, run
from hil.runtime.phases import Phase
from hil.runtime.telemetry import RunTrace, telemetry_columns

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
