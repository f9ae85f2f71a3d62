"""Tests that need the AVR toolchain and simavr (marker ``firmware``: the C firmware, its host library
and its simavr harness, built by ``make -C firmware``).

Without the toolchain they are skipped, all from this one place, so pytest's ``-ra`` summary shows ONE
line naming the Debian packages (``.ci/apt-packages``). With ``VSCMG_HIL_REQUIRE_ALL=1`` (``.ci/run``
sets it) a missing toolchain stops the run before any test instead, so CI can never pass by skipping.
``VSCMG_HIL_PRETEND_MISSING=pkg,...`` makes the check report those packages missing (to test this file on
a machine that has them).
"""

from __future__ import annotations

import os
import socket

import pytest

from firmware_sim.avr.build import missing_tools, toolchain_message

REQUIRE_ALL = "VSCMG_HIL_REQUIRE_ALL"
PRETEND_MISSING = "VSCMG_HIL_PRETEND_MISSING"


def _missing() -> list[str]:
    pretend = [p for p in os.environ.get(PRETEND_MISSING, "").split(",") if p]
    return sorted(set(missing_tools()) | set(pretend))


_REASON = pytest.StashKey[str]()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    needs = [item for item in items if item.get_closest_marker("firmware") is not None]
    missing = _missing() if needs else []
    if not missing:
        return
    message = toolchain_message(missing)
    if os.environ.get(REQUIRE_ALL) == "1":
        raise pytest.UsageError(f"{REQUIRE_ALL}=1 and {len(needs)} selected tests need it: {message}")
    config.stash[_REASON] = message


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    reason = item.config.stash.get(_REASON, None)
    if reason is not None and item.get_closest_marker("firmware") is not None:
        pytest.skip(reason)  # raised here for every such test: pytest -ra folds them into one line


def _free_port(kind: socket.SocketKind) -> int:
    """A port on the loopback address that nothing holds now (the kernel's pick): a fixed port collides
    with another test run on the same machine (two checkouts, a helper's run)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def phone_port() -> int:
    """A free UDP port for a test's phone stream (SensaGram's datagrams)."""
    return _free_port(socket.SOCK_DGRAM)


@pytest.fixture
def push_port() -> int:
    """A free TCP port for a test's phone stream over HTTP (Sensor Logger's HTTP Push)."""
    return _free_port(socket.SOCK_STREAM)
