"""Fixtures of the board conformance suite.

Every test here takes the ``target`` fixture, parametrised over :data:`conformance.targets.TARGETS`, and
talks to the board only through a real serial port path with pyserial (``conformance.host.connect``).
Adding a board target is one entry in ``TARGETS`` (see targets.py); ``pytest tests/conformance -k simavr``
then runs just that target.

A test about the board's link watchdog carries the marker ``link_watchdog``: its board gets the short
link timeout (``LINK_TIMEOUT_S``); every other test's board a long one (``QUIET_LINK_TIMEOUT_S``), so that
a host a loaded machine leaves unscheduled for a while does not trip a watchdog the test is not about.
"""

from __future__ import annotations

import dataclasses

import pytest

from conformance.host import connect
from conformance.targets import LINK_TIMEOUT_S, QUIET_LINK_TIMEOUT_S, TARGETS, TargetSpec, resolve

SPEC = TargetSpec()


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "link_watchdog: a conformance test about the board's link watchdog (its short timeout)"
    )


def _param(name: str) -> object:
    """A target; one that runs the C firmware needs the toolchain (marker ``firmware``), one on
    ``udp_multicast`` IPv4 multicast between local sockets (marker ``udp_multicast``; tests/conftest.py)."""
    target = TARGETS[name]
    marks = []
    if getattr(target, "needs_firmware_build", False):
        marks.append(pytest.mark.firmware)
    if getattr(target, "needs_multicast", False):
        marks.append(pytest.mark.udp_multicast)
    return pytest.param(name, marks=marks)


@pytest.fixture(params=[_param(name) for name in sorted(TARGETS)])
def target(request):
    about_the_link = request.node.get_closest_marker("link_watchdog") is not None
    spec = dataclasses.replace(
        SPEC, link_timeout_s=LINK_TIMEOUT_S if about_the_link else QUIET_LINK_TIMEOUT_S
    )
    cls = resolve(request.param)
    with cls(spec) as t:
        yield t
        t.check()  # the board must have survived the test


@pytest.fixture
def host(target):
    h = connect(target)
    yield h
    h.close()
