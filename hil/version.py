"""Which ``hil`` this is: the installed package's version and, for a checkout, its git revision.

A run directory and a campaign record both (:func:`describe`), so a result can be traced to the code that
made it, and a campaign's workers can be checked to run the same code as its driver. ``hil --version``
prints them.
"""

from __future__ import annotations

import functools
from pathlib import Path

DISTRIBUTION = "vscmg-hil"
ROOT = Path(__file__).resolve().parents[1]


@functools.cache
def package_version() -> str:
    """The installed distribution's version (``pyproject.toml``), or ``"unknown"`` when it is not
    installed (the sources run from a copy). ``importlib.metadata`` is imported here, when a run's summary
    asks, not before a run's first tick (10-30 ms)."""
    from importlib import metadata

    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "unknown"


@functools.cache
def source_revision() -> str | None:
    """``git describe --always --dirty`` of the checkout the sources run from (``-dirty``: edited since
    that commit), or None when they are not a git checkout or git is missing. ``subprocess`` is imported
    here, when a run's summary asks, not with the module (~3 ms of every ``hil run``'s imports)."""
    import subprocess

    try:
        done = subprocess.run(
            ["git", "describe", "--always", "--dirty"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=10.0,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    if done.returncode != 0 or not (ROOT / ".git").exists():
        return None
    return done.stdout.strip() or None


def describe() -> dict[str, str | None]:
    """``{"version": ..., "revision": ...}``: for ``summary.json`` and a campaign's manifest."""
    return {"version": package_version(), "revision": source_revision()}


def version_line() -> str:
    """What ``hil --version`` prints."""
    revision = source_revision()
    return f"hil (vscmg-hil) {package_version()}" + (f", revision {revision}" if revision else "")


def mismatch(here: dict[str, str | None], there: dict[str, str | None]) -> str | None:
    """Why two :func:`describe` results are not the same code (a campaign's worker against its driver), or
    None. Revisions are compared when both are known (a worker installed from a wheel has none: then the
    versions alone)."""
    if here["version"] != there["version"]:
        return f"version {here['version']} against {there['version']}"
    if here["revision"] and there["revision"] and here["revision"] != there["revision"]:
        return f"revision {here['revision']} against {there['revision']}"
    return None
