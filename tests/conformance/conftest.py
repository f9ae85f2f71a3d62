"""Fixtures of the board conformance suite.

Every test here takes the ``target`` fixture, parametrised over :data:`conformance.targets.TARGETS`, and
talks to the board only through a real serial port path with pyserial (``conformance.host.SerialHost``).
Adding a board target is one entry in ``TARGETS`` (see targets.py); ``pytest tests/conformance -k simavr``
then runs just that target.
"""

from __future__ import annotations

import pytest

from conformance.host import SerialHost
from conformance.targets import TARGETS, TargetSpec, resolve

SPEC = TargetSpec()


def _param(name: str) -> object:
    """A target; one that runs the C firmware needs the toolchain (marker ``firmware``, tests/conftest.py)."""
    needs = getattr(TARGETS[name], "needs_firmware_build", False)
    return pytest.param(name, marks=pytest.mark.firmware) if needs else name


@pytest.fixture(params=[_param(name) for name in sorted(TARGETS)])
def target(request):
    cls = resolve(request.param)
    with cls(SPEC) as t:
        yield t
        t.check()  # the board must have survived the test


@pytest.fixture
def host(target):
    h = SerialHost(target.port)
    yield h
    h.close()
