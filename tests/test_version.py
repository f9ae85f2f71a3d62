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
