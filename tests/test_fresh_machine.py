"""A fresh machine: without the AVR toolchain the tests that need it skip with ONE line naming the
packages of ``.ci/apt-packages``, and without Chromium the browser tests with one more; with
``VSCMG_HIL_REQUIRE_ALL=1`` (CI) either absence fails the run. The absences are pretended with
``VSCMG_HIL_PRETEND_MISSING`` (tests/conftest.py); CI also runs the whole command with the tools really
hidden (``.ci/fresh-machine``)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_sim.avr import build
from firmware_sim.avr.paths import APT_PACKAGES, ROOT

SELECTION = ["tests/test_firmware_codegen.py", "tests/test_firmware_logic.py"]


def _pytest(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("VSCMG_HIL_")}
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args],
        cwd=ROOT, env={**clean, **env}, capture_output=True, text=True, timeout=300,
    )  # fmt: skip


def test_without_the_toolchain_the_firmware_tests_skip_with_one_line_naming_the_packages():
    out = _pytest(*SELECTION, VSCMG_HIL_PRETEND_MISSING="gcc-avr,libsimavr-dev")
    assert out.returncode == 0, out.stdout[-3000:]
    skips = [line for line in out.stdout.splitlines() if line.startswith("SKIPPED")]
    assert len(skips) == 1, skips
    assert all(pkg in skips[0] for pkg in build.apt_packages())
    n_skipped = int(re.search(r"SKIPPED \[(\d+)\]", skips[0]).group(1))
    assert n_skipped >= 10 and re.search(rf"\d+ passed, {n_skipped} skipped", out.stdout)


def test_ci_makes_a_missing_toolchain_a_failure():
    out = _pytest(*SELECTION, VSCMG_HIL_PRETEND_MISSING="gcc-avr", VSCMG_HIL_REQUIRE_ALL="1")
    assert out.returncode not in (0, 5)
    assert "VSCMG_HIL_REQUIRE_ALL=1" in out.stderr and "gcc-avr" in out.stderr
    assert out.stderr.count("apt-get install") == 1  # one message, not one per test


@pytest.mark.firmware  # needs the toolchain itself: skipped with the others where it is missing
def test_with_the_toolchain_nothing_is_skipped_for_it():
    out = _pytest("tests/test_firmware_codegen.py", VSCMG_HIL_REQUIRE_ALL="1")
    assert out.returncode == 0 and "skipped" not in out.stdout, out.stdout[-2000:]


def test_without_chromium_the_browser_tests_skip_with_one_line_naming_the_packages():
    out = _pytest("tests/test_gcs_browser.py", VSCMG_HIL_PRETEND_MISSING="chromium-driver")
    assert out.returncode == 0, out.stdout[-3000:]
    skips = [line for line in out.stdout.splitlines() if line.startswith("SKIPPED")]
    assert len(skips) == 1, skips
    # what is missing, listed: the one pretended missing here (and, on a machine without Chromium at all —
    # the fresh-machine pass — the others too)
    missing = re.search(r"headless Chromium \(([^)]*) missing\)", skips[0])
    assert missing is not None and "chromium-driver" in missing.group(1).split(", "), skips[0]
    assert ".ci/apt-packages" in skips[0]
    assert re.search(r"SKIPPED \[(\d+)\]", skips[0]).group(1) == re.search(
        r"(\d+) skipped", out.stdout
    ).group(1)


def test_ci_makes_a_missing_browser_a_failure():
    out = _pytest(
        "tests/test_gcs_browser.py", VSCMG_HIL_PRETEND_MISSING="chromium", VSCMG_HIL_REQUIRE_ALL="1"
    )
    assert out.returncode not in (0, 5)
    missing = re.search(r"headless Chromium \(([^)]*) missing\)", out.stderr)
    assert "VSCMG_HIL_REQUIRE_ALL=1" in out.stderr and missing is not None, out.stderr[-2000:]
    assert "chromium" in missing.group(1).split(", ")


def test_ci_runs_the_command_again_as_on_a_fresh_machine():
    run = (ROOT / ".ci" / "run").read_text()
    fresh = (ROOT / ".ci" / "fresh-machine").read_text()
    hide = (ROOT / ".ci" / "without-avr-toolchain").read_text()
    assert ".ci/fresh-machine" in run and ".ci/without-avr-toolchain" in fresh
    assert ".venv/bin/python -m pytest" in fresh and "-u VSCMG_HIL_REQUIRE_ALL" in fresh
    assert all(tool in hide for tool in ("/usr/bin/avr-*", "/usr/bin/chromium", "/usr/bin/chromedriver"))


def test_one_list_of_packages_for_ci_the_readme_and_the_message():
    listed = build.apt_packages()
    assert set(build.TOOLS.values()) | set(build.HEADERS.values()) <= set(listed)
    assert ".ci/apt-packages" in (ROOT / ".ci" / "run").read_text()
    readme = (ROOT / "README.md").read_text()
    assert "grep -v '^#' .ci/apt-packages" in readme
    assert not any(re.search(rf"\b{re.escape(p)}\b", readme) for p in ("gcc-avr", "libsimavr-dev")), (
        "the README points to .ci/apt-packages instead of copying it"
    )
    assert "VSCMG_HIL_REQUIRE_ALL=1" in (ROOT / ".ci" / "run").read_text()
    assert APT_PACKAGES.exists()


def test_firmware_sim_avr_without_the_toolchain_is_one_line(monkeypatch, capsys):
    from firmware_sim.cli import main

    monkeypatch.setattr(build, "_built", False)
    monkeypatch.setattr(build, "missing_tools", lambda: ["gcc-avr"])
    assert main(["--avr"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "gcc-avr" in err[0] and ".ci/apt-packages" in err[0]


def test_the_readme_test_command_is_the_one_ci_runs():
    assert "python -m pytest" in (ROOT / "README.md").read_text()
    assert Path(ROOT / ".ci" / "run").read_text().count(".venv/bin/python -m pytest") == 1


def test_ci_runs_every_test_once_with_what_it_needs():
    """CI's two passes split the command: the fresh-machine pass runs it whole with the tools hidden (the
    tests that need them skip there), the pass beside it exactly the tests of the markers whose tools
    ``.ci/without-avr-toolchain`` hides, with them and ``VSCMG_HIL_REQUIRE_ALL=1``. A marker left out of
    ``TOOL_MARKERS`` would have its tests skipped in the one pass and never run in the other; one added for
    a tool the fresh pass keeps (``udp_multicast``) would run them twice for nothing."""
    from conftest import NEEDS

    run = (ROOT / ".ci" / "run").read_text()
    found = re.search(r'^TOOL_MARKERS="([^"]*)"$', run, re.MULTILINE)
    assert found is not None, "TOOL_MARKERS is not set in .ci/run"
    markers = set(found.group(1).split(" or "))
    assert markers == {"firmware", "browser"} and markers <= set(NEEDS)
    assert 'VSCMG_HIL_REQUIRE_ALL=1 .venv/bin/python -m pytest -q -m "$TOOL_MARKERS"' in run
    fresh = (ROOT / ".ci" / "fresh-machine").read_text()
    assert '-m pytest -q "$@"' in fresh, "the fresh-machine pass runs the whole command"
    assert ".ci/fresh-machine >" in run and 'wait "$fresh_pid"' in run
