"""Campaigns beside their tested path (a hunt's findings), each through the real command and real Dask:

1. **The scheduler lost mid-campaign.** A chunk cancelled because the scheduler's connection was lost was
   recorded as failed runs ("chunk lost: FutureCancelledError"), the command closed with "16 runs in 3.7 s"
   and status 1, and a resume never ran those runs again: an incident outside the runs made them failed
   for good. Now such runs are not recorded; the command ends on a :class:`LinkError` naming the scheduler
   and the runs left (status 2), and the same command against a scheduler that is there runs them: the
   campaign ends identical to one never interrupted.
2. **``--board`` is part of the campaign.** A firmware extension of an emulator campaign was accepted and
   pooled both boards' runs in one summary; campaign.json did not say which board ran.
3. **A plain run's wall-time budget.** Only fault campaigns bounded a run's wall time: a run that hung
   held its campaign for ever. Every run now fails ``RunHung`` past its budget.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from montecarlo_support import write_quick_scenario

from hil.cli import main as hil_main
from hil.montecarlo.store import MANIFEST, RUNS
from hil.runtime.runlog import SUMMARY
from protocol.errors import RunHung

DASK = str(Path(sys.executable).with_name("dask"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Cluster:
    """A real ``dask scheduler`` and ``dask worker`` process on the loopback."""

    def __init__(self, tmp: Path) -> None:
        self.port = _free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
        self.scheduler = subprocess.Popen(
            [DASK, "scheduler", "--host", "127.0.0.1", "--port", str(self.port), "--dashboard-address", ":0"],
            stdout=subprocess.DEVNULL,
            stderr=open(tmp / f"scheduler-{self.port}.log", "w"),  # noqa: SIM115 - closed with the process
            env=env,
            start_new_session=True,
        )
        self.worker = subprocess.Popen(
            [DASK, "worker", self.address, "--nthreads", "1", "--nworkers", "1", "--no-dashboard"],
            stdout=subprocess.DEVNULL,
            stderr=open(tmp / f"worker-{self.port}.log", "w"),  # noqa: SIM115
            env=env,
            start_new_session=True,
        )
        self._wait_for_worker()

    def _wait_for_worker(self) -> None:
        from distributed import Client

        deadline = time.monotonic() + 60.0
        with Client(self.address, timeout=30) as client:
            while not client.scheduler_info()["workers"]:
                assert time.monotonic() < deadline, "no worker joined"
                time.sleep(0.2)

    def kill_scheduler(self) -> None:
        os.killpg(self.scheduler.pid, signal.SIGKILL)
        self.scheduler.wait(10)

    def close(self) -> None:
        for proc in (self.worker, self.scheduler):
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)


def _montecarlo(scenario: Path, out: Path, *extra: str) -> subprocess.Popen[str]:
    cmd = [
        sys.executable,
        "-m",
        "hil",
        "montecarlo",
        str(scenario),
        "--runs",
        "10",
        "--seed",
        "5",
        "--batch",
        "1",
    ]
    return subprocess.Popen(
        [*cmd, "--out", str(out), "--no-plots", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
    )


def _rows(out: Path) -> list[str]:
    path = out / RUNS
    return path.read_text().splitlines()[1:] if path.exists() else []


def test_a_scheduler_lost_mid_campaign_leaves_its_runs_to_the_next_session(tmp_path):
    scenario = write_quick_scenario(tmp_path)
    out, reference = tmp_path / "campaign", tmp_path / "reference"
    cluster = _Cluster(tmp_path)
    proc = _montecarlo(scenario, out, "--scheduler", cluster.address)
    try:
        deadline = time.monotonic() + 120.0
        while len(_rows(out)) < 2 and proc.poll() is None:  # some runs done, most to come
            assert time.monotonic() < deadline
            time.sleep(0.05)
        cluster.kill_scheduler()
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:  # it hung on the lost scheduler: never left behind
            proc.kill()
            proc.communicate()
        cluster.close()
    assert proc.returncode == 2, (proc.returncode, stdout, stderr)
    assert cluster.address in stderr and "not run: the same command again runs them" in stderr, stderr
    assert "Traceback" not in stderr, stderr
    rows = _rows(out)
    assert len(rows) < 10 and not [r for r in rows if "chunk lost" in r], rows
    # the same command on a cluster that is there (a local one) runs the rest, and only those
    resumed = _montecarlo(scenario, out, "--workers", "1")
    stdout, stderr = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, stderr
    assert f"{len(rows)} runs were already in {out}" in stderr
    fresh = _montecarlo(scenario, reference, "--workers", "1")
    assert fresh.communicate(timeout=300) and fresh.returncode == 0
    assert sorted(_rows(out)) == sorted(_rows(reference))  # every run once, as if never interrupted


def test_a_finished_campaign_run_again_is_summarised_without_a_cluster(tmp_path):
    """The same command again on a campaign whose runs are all on disk has nothing to run. Before: it
    started a LocalCluster (seconds of worker processes) for nothing, and against a scheduler since gone it
    failed (status 2, "cannot reach the Dask scheduler") instead of summarising what it holds. Now no
    cluster is started or reached: the runs are summarised again, summary.json rewritten, status 0; a
    directory with a run left still needs its cluster (the LinkError as before)."""
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "campaign"
    first = _montecarlo(scenario, out, "--workers", "1")
    assert first.communicate(timeout=300) and first.returncode == 0
    rows = _rows(out)
    (out / SUMMARY).unlink()
    gone = f"tcp://127.0.0.1:{_free_port()}"  # nothing listens there
    again = _montecarlo(scenario, out, "--scheduler", gone)
    stdout, stderr = again.communicate(timeout=120)
    assert again.returncode == 0, stderr
    assert "summarised again, no cluster" in stderr and f"{len(rows)} runs were already in {out}" in stderr
    assert "Traceback" not in stderr, stderr
    assert _rows(out) == rows and json.loads((out / SUMMARY).read_text())["runs"] == len(rows)
    lines = (out / RUNS).read_text().splitlines()
    (out / RUNS).write_text("\n".join(lines[:-1]) + "\n")  # one run left to do
    left = _montecarlo(scenario, out, "--scheduler", gone)
    _, stderr = left.communicate(timeout=120)
    assert left.returncode == 2 and gone in stderr and "Traceback" not in stderr, stderr


def test_a_campaign_on_another_board_is_refused_in_its_directory(tmp_path, capsys):
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mix"
    base = ["montecarlo", str(scenario), "--runs", "1", "--seed", "3", "--workers", "1", "--no-plots"]
    assert hil_main([*base, "--out", str(out)]) == 0
    assert '"board": "emulator"' in (out / MANIFEST).read_text()
    capsys.readouterr()
    assert hil_main([*base[:3], "2", *base[4:], "--board", "firmware", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "board 'emulator', not 'firmware'" in err and str(out / MANIFEST) in err, err
    assert len(_rows(out)) == 1  # nothing run


_HUNG_RUN = """
import sys
from hil.montecarlo import runner
from hil.montecarlo.dispersions import draw, load_dispersions
from hil.scenario import load_scenario
sc = load_scenario(sys.argv[1])
run = draw(load_dispersions(None, sc), 1, 0)
runner.WALL_BUDGET_S, runner.WALL_PER_SIM_S = 0.0, float(sys.argv[2])
print(runner.run_one(sc, run, trace_hz=10.0).error)
"""


@pytest.mark.parametrize("per_sim_s", [1e-4, 3e-4, 1e-3])
def test_a_plain_run_past_its_wall_budget_fails_run_hung(tmp_path, per_sim_s):
    """A run's budget scaled down to a few ms, so that the interrupt lands at drawn places of the run's
    start (imports, the transport's opening, the loop): the run fails, ``RunHung`` — a run that hung is
    bounded. Before: the interrupt was a ``TimeoutError``, and landing in importlib's ``except OSError``
    (or any handler that goes on) it was lost: the run finished "ok", CI 1 in ~3 here. In a process of its
    own: an interrupt that lands in an import leaves that module half made for the rest of the process
    (a campaign's budget of minutes never comes while a worker imports; this test's of ms does)."""
    scenario = write_quick_scenario(tmp_path)
    done = subprocess.run(
        [sys.executable, "-c", _HUNG_RUN, str(scenario), repr(per_sim_s)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().startswith("RunHung"), (done.stdout, done.stderr[-2000:])


_CAUGHT = """
import sys, time
from hil.montecarlo import runner
from protocol.errors import HilError, RunHung
catch = {"Exception": Exception, "HilError": HilError}[sys.argv[1]]
caught = 0
try:
    with runner.wall_budget(0.05, again_s=0.05):
        deadline = time.monotonic() + 0.4
        while time.monotonic() < deadline:
            try:
                time.sleep(0.005)
            except catch:
                caught += 1
except RunHung as exc:
    print("RunHung:", exc)
print("caught", caught)
deadline = time.monotonic() + 0.3
while time.monotonic() < deadline:
    time.sleep(0.005)  # nothing pending or coming: no RunHung out of the block
with runner.wall_budget(5.0):
    time.sleep(0.01)
print("after: nothing raised")
"""


@pytest.mark.parametrize("catch", ["Exception", "HilError"])
def test_the_wall_budget_holds_where_its_interrupt_is_caught_and_raises_nothing_after(tmp_path, catch):
    """A block that catches the interrupt and goes on (an ``except`` that logs and retries) still fails
    ``RunHung`` — the interrupt comes again, and the block's end says it went past its budget — and nothing
    is raised into the thread after the block; a block within its budget is left alone. No ``except
    OSError`` takes it for an I/O error. In a process of its own: interrupts raised into pytest's own
    thread left a later test (a signal's handling traced call by call) hanging until its timeout."""
    assert not issubclass(RunHung, OSError)
    done = subprocess.run(
        [sys.executable, "-c", _CAUGHT, catch], capture_output=True, text=True, timeout=120, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert lines[0].startswith("RunHung: past its wall budget of 0.05 s"), done.stdout
    assert int(lines[1].split()[1]) >= 2  # raised again while the block went on
    assert lines[2] == "after: nothing raised"
