"""What a campaign tells about its runs (issue 25, finding 6): a campaign with failed runs exits non-zero.

Real clusters throughout: a LocalCluster of worker processes where a process has to die, in-process threads
where nothing needs a process. Runs are short (0.5 s warm-up, 1 s after the slew's start, ~0.3 s of CPU
each), and nothing here waits on a fixed delay, so a busy CPU only makes the tests slower.
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from hil.cli import main as hil_main
from hil.montecarlo import read_runs
from hil.montecarlo.store import RUNS
from hil.scenario import SCENARIO_DIR, load_scenario

DISPERSIONS = """
[spacecraft]
inertia_scale = { dist = "normal", sigma = 0.05 }
[sensors.gyr]
noise = { dist = "normal", relative_sigma = 0.2, low = 0.0 }
[manoeuvre]
angle_deg = { dist = "normal", relative_sigma = 0.1 }
"""

EVERY_RUN_FAILS = """
[sensors.gyr]
noise = { dist = "uniform", low = -2.0, high = -1.0 }   # a negative noise: the model refuses every draw
"""


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory) -> Path:
    """cubesat-1u, shortened: 0.5 s warm-up, a 20° slew, 1 s after its start."""
    text = (SCENARIO_DIR / "cubesat-1u.toml").read_text()
    for old, new in (
        ("duration_s = 35.0", "duration_s = 1.0"),
        ("warmup_s = 2.0", "warmup_s = 0.5"),
        ("angle_deg = 90.0", "angle_deg = 20.0"),
    ):
        assert old in text
        text = text.replace(old, new)
    path = tmp_path_factory.mktemp("scenario") / "quick.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def scenario(scenario_file):
    return load_scenario(scenario_file)


def _row_indices(out: Path) -> list[int]:
    """The run index of every row of runs.csv, duplicates kept (read_runs keeps the last of an index)."""
    with open(out / RUNS, newline="") as f:
        return [int(row[0]) for row in list(csv.reader(f))[1:]]


def _cli(scenario_file: Path, dispersions: Path, out: Path, scheduler: str, runs: int) -> int:
    return hil_main(
        [
            "montecarlo",
            str(scenario_file),
            "--runs",
            str(runs),
            "--seed",
            "1",
            "--dispersions",
            str(dispersions),
            "--scheduler",
            scheduler,
            "--out",
            str(out),
            "--no-plots",
        ]
    )


def test_a_campaign_with_failed_runs_exits_non_zero(scenario_file, tmp_path, capsys):
    """Through the command's entry point: every run failing is status 1 (it used to be 0), and so is a
    resumed campaign whose directory holds those failures (they are skipped, not forgotten); the statuses
    are in the command's help."""
    from distributed import LocalCluster

    failing = tmp_path / "failing.toml"
    failing.write_text(EVERY_RUN_FAILS)
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address="127.0.0.1:0"
    ) as cluster:
        assert _cli(scenario_file, failing, tmp_path / "all", cluster.scheduler_address, 3) == 1
        printed = capsys.readouterr()
        assert "3 runs, 0 ok, 3 failed" in printed.out
        assert "hil montecarlo: 3 of 3 runs failed (exit status 1)" in printed.err
        assert _cli(scenario_file, failing, tmp_path / "all", cluster.scheduler_address, 3) == 1
        assert "3 runs were already in" in capsys.readouterr().err
    assert read_runs(tmp_path / "all").ok.sum() == 0
    with pytest.raises(SystemExit):
        hil_main(["montecarlo", "--help"])
    help_text = capsys.readouterr().out
    assert "exit status:" in help_text and "1    at least one run in OUT failed" in help_text
