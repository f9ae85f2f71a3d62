"""``hil --version`` names the installed package's version and the checkout's revision (a campaign's
workers and a run directory are traced to the code by them)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

from hil.version import describe

ROOT = Path(__file__).resolve().parents[1]


def test_hil_version_names_the_package_and_the_revision():
    out = subprocess.run(
        [sys.executable, "-m", "hil", "--version"], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert out.stdout.startswith(f"hil (vscmg-hil) {version}")
    revision = describe()["revision"]
    if (ROOT / ".git").exists():
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip()
        assert revision is not None and head[:7] in revision
        assert f"revision {revision}" in out.stdout


def test_a_worker_running_other_code_refuses_the_campaigns_chunk():
    """A campaign's worker checks it runs the driver's code (hil --version's version and revision): one of
    another version, or another revision of a checkout, refuses the chunk, naming both; a worker
    installed without git (no revision) is judged by the version alone."""
    import pytest

    from hil.montecarlo.campaign import stream_chunk
    from hil.scenario import load_scenario
    from hil.version import mismatch
    from protocol.errors import ConfigError

    here = describe()
    assert mismatch(here, dict(here)) is None
    assert mismatch({"version": "0.1.0", "revision": None}, {"version": "0.1.0", "revision": "abc"}) is None
    assert "version 0.1.0 against 9.9" in str(
        mismatch({"version": "0.1.0", "revision": None}, {"version": "9.9", "revision": None})
    )
    other = {"version": here["version"], "revision": "0000000-elsewhere"}
    if here["revision"]:
        with pytest.raises(ConfigError) as refused:
            stream_chunk(load_scenario("cubesat-1u"), [], 5.0, "session", other)
        assert "other code than the campaign's driver" in str(refused.value)
        assert "0000000-elsewhere" in str(refused.value)
    assert stream_chunk(load_scenario("cubesat-1u"), [], 5.0, "session", here) == []
