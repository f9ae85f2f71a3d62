"""An output folder that already holds another command's outputs, and an empty ``--out``.

``hil replay --out`` or ``hil montecarlo --out`` given a run's directory wrote their summary.json over the
run's, beside its telemetry and events, exit 0: the run's record was lost. Each command now refuses a
folder holding another's outputs (:data:`hil.files.output.OUTPUTS_OF`), naming the file that tells, before
any work, and leaves it as it was. ``--out ""`` (an unset shell variable) was the current directory."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from montecarlo_support import write_quick_scenario

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT.parent / "shared" / "data" / "broad" / "01_undisturbed_slow_rotation_A.mat"
FOLDERS = {
    "run": {"telemetry.csv": "t,phase\n0.0,1\n", "events.jsonl": '{"t": 0.0, "kind": "armed"}\n'},
    "replay": {"estimates.csv": "t,rx,ry,rz\n0.0,0,0,0\n"},
    "campaign": {"campaign.json": "{}\n"},
}


def hil(*argv: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", *argv], capture_output=True, text=True, timeout=600, cwd=cwd
    )


def folder_of(kind: str, where: Path) -> dict[str, bytes]:
    """A folder as ``kind``'s command leaves it, with its summary.json; what it holds, to compare after."""
    where.mkdir(parents=True)
    for name, text in {**FOLDERS[kind], "summary.json": '{"exit": "completed"}\n'}.items():
        (where / name).write_text(text)
    return {p.name: p.read_bytes() for p in where.iterdir()}


@pytest.mark.parametrize("kind", ["run", "campaign"])
def test_a_replay_into_another_commands_folder_is_refused_and_leaves_it(tmp_path, kind):
    if not LOG.is_file():
        pytest.skip(f"the shared data is not beside the project: {LOG}")
    out = tmp_path / kind
    before = folder_of(kind, out)
    done = hil("replay", str(LOG), "--out", str(out), "--no-plots")
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    tell = next(iter(FOLDERS[kind]))
    assert f"{out}: " in done.stderr and f"is here ({tell})" in done.stderr, done.stderr[-2000:]
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


@pytest.mark.parametrize("kind", ["run", "replay"])
def test_a_campaign_into_another_commands_folder_is_refused_and_leaves_it(tmp_path, kind):
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / kind
    before = folder_of(kind, out)
    done = hil("montecarlo", str(scenario), "--runs", "1", "--workers", "1", "--no-plots", "--out", str(out))
    assert done.returncode != 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
    tell = next(iter(FOLDERS[kind]))
    assert f"is here ({tell})" in done.stderr, done.stderr[-2000:]
    after = {p.name: p.read_bytes() for p in out.iterdir() if not p.name.startswith(".")}  # its lock file
    assert after == before


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "--out", ""],
        ["replay", "log.csv", "--out", ""],
        ["montecarlo", "cubesat-1u", "--out", ""],
        ["calibrate", "fit", "a.csv", "-o", ""],
    ],
)
def test_an_empty_out_is_refused_not_taken_for_the_current_directory(tmp_path, argv):
    done = hil(*argv, cwd=tmp_path)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert "'' is an empty path (an unset shell variable?)" in done.stderr
    assert list(tmp_path.iterdir()) == []  # nothing written where it ran
