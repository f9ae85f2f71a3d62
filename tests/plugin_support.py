"""Pieces the plugin tests' misbehaving plugins share (tests/test_plugin_*.py and
tests/test_plugins_beside_*.py): a phone lying still, and an estimator that is the built-in one but where
a test says otherwise."""

from __future__ import annotations

import sys
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from hil.estimation.registry import register_estimator
from hil.estimation.sensors import SensorKind, SensorSample

STILL_PERIOD_S = 0.005
"""s: the still phone's sample period (200 Hz of the run's clock)."""


def still_samples(next_t: float, now: float) -> tuple[list[SensorSample], float]:
    """A phone lying still: its samples from ``next_t`` up to ``now`` (s, the run's clock), every sensor at
    each instant, and the time of the next one."""
    out: list[SensorSample] = []
    while next_t <= now:
        out += [
            SensorSample(next_t, SensorKind.GYR, (0.0, 0.0, 0.0)),
            SensorSample(next_t, SensorKind.ACC, (0.0, 0.0, 9.81)),
            SensorSample(next_t, SensorKind.MAG, (20.0, 0.0, -40.0)),
        ]
        next_t += STILL_PERIOD_S
    return out, next_t


class Delegating:
    """An estimator that is ``inner`` (the built-in one) in every call a subclass does not take over."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def step(self, s: Any) -> Any:
        return self.inner.step(s)

    def run(self, steps: Any, progress: Any = None) -> Any:
        return self.inner.run(steps, progress)

    @property
    def gyro_bias(self) -> Any:
        return self.inner.gyro_bias

    def set_gyro_bias(self, b: Any) -> None:
        self.inner.set_gyro_bias(b)

    def set_rest_learning(self, on: bool) -> None:
        self.inner.set_rest_learning(on)


@contextmanager
def estimators_in_a_module(module: str, kinds: Mapping[str, tuple[str, Any]]) -> Iterator[None]:
    """Estimator kinds registered by name as ``module:ATTRIBUTE`` of a module made for the test and put in
    ``sys.modules`` while it runs: ``kinds`` maps each registered name to (attribute, kind)."""
    made = type(sys)(module)
    for name, (attribute, kind) in kinds.items():
        setattr(made, attribute, kind)
        register_estimator(name, f"{module}:{attribute}")
    sys.modules[module] = made
    try:
        yield
    finally:
        del sys.modules[module]
