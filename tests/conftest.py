"""Tests that need tools beyond Python, one marker per kind, all skipped from this one place:

* ``firmware``: the AVR toolchain and simavr (the C firmware, its host library and its simavr harness,
  built by ``make -C firmware``);
* ``browser``: a headless Chromium driven through chromedriver by Selenium (the ground station's page);
* ``udp_multicast``: IPv4 multicast between two sockets on this machine (python-can's ``udp_multicast``
  CAN interface; a sandbox without a multicast route lacks it: ``tests/can_support.py`` tries it).

Without the tools those tests are skipped, each kind with ONE reason, so pytest's ``-ra`` summary shows one
line per kind naming the Debian packages to install (``.ci/apt-packages``, the one list). With
``VSCMG_HIL_REQUIRE_ALL=1`` (``.ci/run`` sets it) a missing tool stops the run before any test instead, so
CI can never pass by skipping. ``VSCMG_HIL_PRETEND_MISSING=pkg,...`` makes the checks report those packages
missing (to test this file on a machine that has them): ``gcc-avr``, ``libsimavr-dev``, ... for the
firmware, ``chromium``, ``chromium-driver`` or ``selenium`` for the browser.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
import socket
from collections.abc import Callable

import pytest
from hypothesis import settings

from firmware_sim.avr.build import install_hint, missing_tools, toolchain_message

# No property test has a deadline: none of them checks its own speed (bench/ measures that), and on a
# loaded CI machine a first call that compiles a kernel, or a slice the scheduler took away, exceeded
# Hypothesis's 200 ms default and failed tests whose every assertion held.
settings.register_profile("vscmg-hil", deadline=None)
settings.load_profile("vscmg-hil")

# A test run started in the background by a non-interactive shell (`cmd &`, as CI runners and nohup do)
# inherits SIGINT ignored, and every process it starts would too: the tests that press Ctrl-C on a
# `python -m hil` subprocess (calibration, runs) would see it ignored. Ctrl-C is restored for them here;
# a signal handler, unlike SIG_IGN, is not inherited through exec, so each child starts with the default.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

REQUIRE_ALL = "VSCMG_HIL_REQUIRE_ALL"
PRETEND_MISSING = "VSCMG_HIL_PRETEND_MISSING"
CHROMIUM = os.environ.get("VSCMG_HIL_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("VSCMG_HIL_CHROMEDRIVER", "/usr/bin/chromedriver")


def _pretended() -> set[str]:
    return {p for p in os.environ.get(PRETEND_MISSING, "").split(",") if p}


def _firmware_missing() -> list[str]:
    return sorted(set(missing_tools()) | (_pretended() - {"chromium", "chromium-driver", "selenium"}))


def _browser_missing() -> list[str]:
    """Debian packages (or ``selenium``) missing for the browser tests. An executable is what counts:
    a path that exists but cannot be run (hidden by ``.ci/without-avr-toolchain``) is missing."""
    missing = {pkg for path, pkg in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver"))
               if shutil.which(path) is None}  # fmt: skip
    if importlib.util.find_spec("selenium") is None:
        missing.add("selenium")
    return sorted(missing | (_pretended() & {"chromium", "chromium-driver", "selenium"}))


def _browser_message(missing: list[str]) -> str:
    debs = [m for m in missing if m != "selenium"]
    parts = [f"the ground station's browser tests need a headless Chromium ({', '.join(missing)} missing)"]
    if debs:
        parts.append(install_hint())
    if "selenium" in missing:
        parts.append("pip install -e '.[test]' (selenium)")
    return "; ".join(parts)


def _multicast_missing() -> list[str]:
    from can_support import udp_multicast_problem

    problem = udp_multicast_problem()
    return [] if problem is None else [problem]


def _multicast_message(missing: list[str]) -> str:
    return f"the CAN tests over udp_multicast need IPv4 multicast between local sockets: {missing[0]}"


NEEDS: dict[str, tuple[Callable[[], list[str]], Callable[[list[str]], str]]] = {
    "firmware": (_firmware_missing, toolchain_message),
    "browser": (_browser_missing, _browser_message),
    "udp_multicast": (_multicast_missing, _multicast_message),
}
"""marker -> (what is missing for its tests, the one line saying what to install)."""

_REASONS = pytest.StashKey[dict[str, str]]()


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(  # ``firmware`` is declared in pyproject.toml
        "markers",
        "browser: needs chromium and chromedriver (.ci/apt-packages) and selenium; skipped without, "
        "unless VSCMG_HIL_REQUIRE_ALL=1",
    )
    config.addinivalue_line(
        "markers",
        "udp_multicast: needs IPv4 multicast between local sockets (python-can's udp_multicast); skipped "
        "without, unless VSCMG_HIL_REQUIRE_ALL=1",
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    reasons: dict[str, str] = {}
    needed: dict[str, int] = {}
    for marker, (missing_of, message_of) in NEEDS.items():
        n = sum(1 for item in items if item.get_closest_marker(marker) is not None)
        missing = missing_of() if n else []
        if missing:
            reasons[marker], needed[marker] = message_of(missing), n
    if reasons and os.environ.get(REQUIRE_ALL) == "1":
        raise pytest.UsageError(
            "\n".join(
                f"{REQUIRE_ALL}=1 and {needed[m]} selected tests need it: {r}" for m, r in reasons.items()
            )
        )
    config.stash[_REASONS] = reasons


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    reasons = item.config.stash.get(_REASONS, {})
    for marker, reason in reasons.items():
        if item.get_closest_marker(marker) is not None:
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
