"""The host's runtime: one closed-loop run against a board (:mod:`hil.runtime.loop`) around the host's
estimator and controller (:mod:`hil.runtime.host`)."""

from hil.runtime.host import Host, Phase, TruthSample, telemetry_columns
from hil.runtime.loop import ReplayInput, RunOptions, RunResult, run

__all__ = [
    "Host",
    "Phase",
    "ReplayInput",
    "RunOptions",
    "RunResult",
    "TruthSample",
    "run",
    "telemetry_columns",
]
