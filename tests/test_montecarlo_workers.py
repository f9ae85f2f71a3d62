"""What a campaign tells about its workers and its runs (issue 25, finding 6): a Dask worker lost mid-campaign
is reported as it happens and counted (its runs still land in runs.csv exactly once), a campaign with failed
runs exits non-zero, and each run's row reaches runs.csv as that run finishes, not with its chunk.

Real clusters throughout: a LocalCluster of worker processes where a process has to die, in-process threads
where nothing needs a process. Runs are short (0.5 s warm-up, 1 s after the slew's start, ~0.3 s of CPU
each), and nothing here waits on a fixed delay, so a busy CPU only makes the tests slower.
"""

from __future__ import annotations

import csv
import json
import os
import signal
from pathlib import Path

import pytest

from hil.cli import main as hil_main
from hil.montecarlo import Campaign, open_client, parse_dispersions, read_runs, run_campaign
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


def test_a_worker_killed_mid_campaign_is_reported_counted_and_its_runs_land_once(scenario, tmp_path):
    """SIGKILL to a worker process busy in a chunk, from the first result's callback: the loss reaches
    ``on_worker_lost`` once (the worker, the chunk it had, that Dask retries it), is counted in the report,
    in summary.json and in the command's closing line, and every run is in runs.csv exactly once: the
    killed chunk's runs that had already streamed back are not written again when the retry reruns them."""
    campaign = Campaign(scenario, parse_dispersions(DISPERSIONS, scenario), runs=8, seed=5, batch=3)
    out = tmp_path / "mc"
    killed: list[str] = []
    losses = []
    with open_client(workers=2) as client:

        def kill_a_busy_worker(result, done, total):
            if killed:
                return
            processing = client.processing()  # worker -> its tasks (running, and queued on it)
            busiest = max(processing, key=lambda address: len(processing[address]))
            assert processing[busiest], "no worker busy after the first result"
            pid = client.run(os.getpid, workers=[busiest])[busiest]
            os.kill(pid, signal.SIGKILL)
            killed.append(busiest)

        report = run_campaign(
            campaign, out, client, on_result=kill_a_busy_worker, on_worker_lost=losses.append, plots=False
        )
    assert [loss.worker for loss in losses] == killed
    loss = losses[0]
    assert loss.tasks >= 1 and loss.runs >= 1 and loss.retried == loss.tasks and loss.given_up == 0
    assert report.workers_lost == 1 and report.losses == losses
    assert json.loads((out / "summary.json").read_text())["workers_lost"] == 1
    assert sorted(_row_indices(out)) == list(range(8))  # every run once: none lost, none twice
    assert read_runs(out).ok.all() and report.completed == 8 and report.failed == 0
    from hil.cli.montecarlo import closing_line

    assert "on 2 workers, 1 worker lost" in closing_line(report)


def test_rows_reach_runs_csv_as_each_run_finishes(scenario, tmp_path):
    """One chunk of three runs on one worker: when the first and the second result are announced their
    rows are already in runs.csv, while the chunk is still running on the worker (before, a chunk's rows
    landed together when the whole chunk had finished)."""
    campaign = Campaign(scenario, parse_dispersions(DISPERSIONS, scenario), runs=3, seed=2, batch=3)
    seen: list[tuple[int, int, int]] = []
    with open_client(workers=1, processes=False) as client:

        def look(result, done, total):
            rows = _row_indices(tmp_path)
            running = sum(len(keys) for keys in client.processing().values())
            assert rows[-1] == result.index
            seen.append((done, len(rows), running))

        report = run_campaign(campaign, tmp_path, client, on_result=look, plots=False)
    assert [(done, rows) for done, rows, _ in seen] == [(1, 1), (2, 2), (3, 3)]
    assert [running for _, _, running in seen[:2]] == [1, 1]  # the chunk still at work on its next run
    assert report.completed == 3 and sorted(_row_indices(tmp_path)) == [0, 1, 2]


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
