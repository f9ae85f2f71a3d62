"""A dispersion file given as something other than a plain file.

A scenario is read from a pipe (``hil montecarlo <(…)``: read once), and a folder or a device given for it
is refused saying which. A dispersion file was resolved by a rule of its own: ``--dispersions <(…)``, a
folder and ``/dev/null`` were each "no such dispersion file" — there they were — and the process
substitution a scenario takes was refused. Both now go through one resolver
(:func:`hil.scenario.paths.resolve_named_file`).
"""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from montecarlo_support import write_quick_scenario

from hil.montecarlo.store import read_runs

INERTIA = "[spacecraft]\ninertia_scale = { dist = 'normal', mean = 1.0, sigma = 0.05 }\n"


def _montecarlo(scenario: Path, dispersions: str, out: Path) -> subprocess.CompletedProcess[str]:
    """``hil montecarlo`` under bash, so that ``dispersions`` may be a process substitution."""
    command = " ".join(
        [shlex.quote(sys.executable), "-m", "hil", "montecarlo", shlex.quote(str(scenario)),
         "--dispersions", dispersions, "--runs", "1", "--workers", "1", "--out", shlex.quote(str(out)),
         "--no-plots"]
    )  # fmt: skip
    return subprocess.run(["bash", "-c", command], capture_output=True, text=True, timeout=280)


def test_a_dispersion_file_read_from_a_pipe_runs_its_campaign(tmp_path):
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mc"
    done = _montecarlo(scenario, f"<(printf {shlex.quote(INERTIA)})", out)
    assert done.returncode == 0, done.stderr
    results = read_runs(out)
    assert len(results) == 1 and "spacecraft.inertia_scale.x" in results.values


@pytest.mark.parametrize(
    "given, said",
    [("folder", "a folder, not a dispersion file"), ("/dev/null", "a character device, not a file")],
)
def test_a_folder_or_a_device_for_dispersions_is_refused_saying_what_it_is(tmp_path, given, said):
    scenario = write_quick_scenario(tmp_path)
    path = tmp_path / "folder" if given == "folder" else Path(given)
    path.mkdir(exist_ok=True) if given == "folder" else None
    out = tmp_path / "mc"
    done = _montecarlo(scenario, shlex.quote(str(path)), out)
    assert done.returncode == 2, done.stderr
    assert f"{path}: {said}" in done.stderr, done.stderr
    assert "no such" not in done.stderr and "Traceback" not in done.stderr
    assert not out.exists()
