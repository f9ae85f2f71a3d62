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


@pytest.fixture(params=sorted(TARGETS))
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
