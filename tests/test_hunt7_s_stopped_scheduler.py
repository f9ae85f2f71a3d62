"""A campaign on a scheduler of your own (``--scheduler``) that stops answering without closing its
connection — the ``dask scheduler`` process SIGSTOPped, its VM frozen, a network that drops packets —
waited for ever: the progress bar stood still past 100 s, no message. Now the driver asks the scheduler
who it is every few seconds, and a scheduler silent for Dask's connect timeout
(``distributed.comm.timeouts.connect``) ends the session: a LinkError naming the scheduler ("not
answering for N s", status 2), the runs done kept, campaign.json's session record ``stopped``, within a
bound — while a scheduler merely paused for a few seconds (a long GC pause) ends nothing. Real ``dask
scheduler`` and ``dask worker`` processes; every wait is bounded; the scheduler is always continued and
killed."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from dask_support import dask_env, free_port
from montecarlo_support import write_quick_scenario

from hil.montecarlo.store import RUNS, read_runs

ROOT = Path(__file__).resolve().parents[1]
DASK = str(Path(sys.executable).with_name("dask"))
SILENT_S = 5  # the driver's Dask connect timeout: how long a silent scheduler is waited for
BOUND_S = 60.0


class _Cluster:
    """A real ``dask scheduler`` on the loopback and one ``dask worker`` (with its nanny), each in a
    session of its own, killed as a group (continued first: a stopped process group dies of SIGKILL all
    the same, but its children must not be left stopped)."""

    def __init__(self, tmp: Path) -> None:
        port = free_port()
        self.address = f"tcp://127.0.0.1:{port}"
        self.scheduler = subprocess.Popen(
            [DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0"],
            stdout=subprocess.DEVNULL,
            stderr=open(tmp / f"scheduler-{port}.log", "w"),  # noqa: SIM115 - closed with the process
            env=dask_env(),
            start_new_session=True,
        )
        self.worker = subprocess.Popen(
            [DASK, "worker", self.address, "--nthreads", "1", "--no-dashboard"],
            stdout=subprocess.DEVNULL,
            stderr=open(tmp / f"worker-{port}.log", "w"),  # noqa: SIM115
            env=dask_env(),
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

    def stop_scheduler(self) -> None:
        os.killpg(self.scheduler.pid, signal.SIGSTOP)

    def continue_scheduler(self) -> None:
        if self.scheduler.poll() is None:
            os.killpg(self.scheduler.pid, signal.SIGCONT)

    def close(self) -> None:
        for proc in (self.worker, self.scheduler):
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGCONT)
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)


def _montecarlo(scenario: Path, out: Path, runs: int, address: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", str(runs), "--seed", "3",
           "--batch", "1", "--duration", "2", "--out", str(out), "--no-plots",
           "--scheduler", address]  # fmt: skip
    env = dask_env(DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=f"{SILENT_S}s")
    return subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


def _wait_for_rows(proc: subprocess.Popen[str], out: Path, rows: int) -> None:
    deadline = time.monotonic() + 120.0
    while _rows(out) < rows and proc.poll() is None:
        assert time.monotonic() < deadline, "no runs written"
        time.sleep(0.02)


def _end(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.communicate()


@pytest.mark.parametrize("seed", [1, 2])
def test_a_scheduler_stopped_at_a_drawn_moment_ends_the_campaign_naming_it_within_a_bound(tmp_path, seed):
    rng = random.Random(seed)
    after_rows, then_s = rng.randint(1, 3), rng.uniform(0.0, 0.5)  # runs under way
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mc"
    cluster = _Cluster(tmp_path)
    proc = _montecarlo(scenario, out, 40, cluster.address)
    try:
        _wait_for_rows(proc, out, after_rows)
        time.sleep(then_s)
        if proc.poll() is not None:
            pytest.skip("the campaign ended before its scheduler was stopped")
        cluster.stop_scheduler()
        stopped_at = time.monotonic()
        try:
            stdout, stderr = proc.communicate(timeout=BOUND_S)
        except subprocess.TimeoutExpired:
            pytest.fail(f"hil montecarlo still waiting on a stopped scheduler {BOUND_S:g} s on (a hang)")
        took_s = time.monotonic() - stopped_at
    finally:
        _end(proc)
        cluster.continue_scheduler()
        cluster.close()
    assert proc.returncode == 2, (proc.returncode, stdout, stderr[-3000:])
    assert "Traceback" not in stderr, stderr[-3000:]
    assert f"{cluster.address}: not answering for {SILENT_S} s" in stderr, stderr[-3000:]
    assert "not run: the same command again runs them" in stderr, stderr[-3000:]
    assert took_s >= SILENT_S - 0.5, took_s  # not before the scheduler had been silent that long
    on_disk = read_runs(out)
    assert len(on_disk) < 40 and on_disk.ok.all()
    session = json.loads((out / "campaign.json").read_text())["session"]
    assert session["state"] == "stopped" and "not answering" in session["error"], session


def test_a_scheduler_paused_for_a_moment_ends_nothing(tmp_path):
    """A scheduler that stops answering for less than the connect timeout (a long GC pause) and then
    answers again: the campaign finishes every run, status 0."""
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mc"
    cluster = _Cluster(tmp_path)
    proc = _montecarlo(scenario, out, 6, cluster.address)
    try:
        _wait_for_rows(proc, out, 1)
        cluster.stop_scheduler()
        time.sleep(SILENT_S - 2.5)
        cluster.continue_scheduler()
        stdout, stderr = proc.communicate(timeout=180)
    finally:
        _end(proc)
        cluster.continue_scheduler()
        cluster.close()
    assert proc.returncode == 0, (proc.returncode, stdout, stderr[-3000:])
    assert sorted(read_runs(out).index) == list(range(6))
