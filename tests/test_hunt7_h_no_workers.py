"""A campaign on a scheduler of your own (``--scheduler``) whose cluster has no worker left — every
``dask worker`` SIGKILLed mid-campaign, or a worker whose Python lacks vscmg-hil (its stream breaks on the
task's unpickling and it closes) — waited for ever: the progress bar stood still, no message, until
Ctrl-C. Now the session ends after ``distributed.scheduler.no-workers-timeout`` (default
:data:`hil.montecarlo.campaign.NO_WORKERS_S`) without a worker: a LinkError naming the scheduler and the runs
left (status 2), the runs done kept, none recorded failed, and the same command on a cluster that is there
finishes the campaign with every run once. Real ``dask scheduler`` and ``dask worker`` processes; every wait
is bounded."""

from __future__ import annotations

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
RUNS_ASKED = 6
NO_WORKERS = "3s"  # the driver's wait for a worker; the scheduler's own setting is left at Dask's (none)


class _Cluster:
    """A real ``dask scheduler`` on the loopback and one ``dask worker`` (with its nanny) started in
    ``worker_env`` (None: no worker); every process in a session of its own, killed as a group."""

    worker: subprocess.Popen[bytes] | None

    def __init__(self, tmp: Path, worker_env: dict[str, str] | None) -> None:
        port = free_port()
        self.address = f"tcp://127.0.0.1:{port}"
        self.scheduler = subprocess.Popen(
            [DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0"],
            stdout=subprocess.DEVNULL,
            stderr=open(tmp / f"scheduler-{port}.log", "w"),  # noqa: SIM115 - closed with the process
            env=dask_env(),
            start_new_session=True,
        )
        self.worker = (
            None
            if worker_env is None
            else subprocess.Popen(
                [DASK, "worker", self.address, "--nthreads", "1", "--no-dashboard"],
                stdout=subprocess.DEVNULL,
                stderr=open(tmp / f"worker-{port}.log", "w"),  # noqa: SIM115
                env=worker_env,
                start_new_session=True,
            )
        )
        self._wait_for_workers(0 if worker_env is None else 1)

    def _wait_for_workers(self, count: int) -> None:
        from distributed import Client

        deadline = time.monotonic() + 60.0
        with Client(self.address, timeout=30) as client:
            while len(client.scheduler_info()["workers"]) < count:
                assert time.monotonic() < deadline, "no worker joined"
                time.sleep(0.2)

    def kill_worker(self) -> None:
        assert self.worker is not None
        os.killpg(self.worker.pid, signal.SIGKILL)  # the nanny and its worker: nothing restarts it
        self.worker.wait(10)

    def close(self) -> None:
        for proc in (self.worker, self.scheduler):
            if proc is not None and proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)


def _montecarlo(scenario: Path, out: Path, *extra: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", str(RUNS_ASKED), "--seed", "3",
           "--batch", "1", "--duration", "2", "--out", str(out), "--no-plots", *extra]  # fmt: skip
    env = dask_env(DASK_DISTRIBUTED__SCHEDULER__NO_WORKERS_TIMEOUT=NO_WORKERS)
    return subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


def _finish(proc: subprocess.Popen[str], within_s: float) -> tuple[str, str]:
    """The command's output once it ends, which must be within ``within_s``: a hang is killed and failed."""
    try:
        return proc.communicate(timeout=within_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"hil montecarlo still waiting {within_s:g} s on (a hang)")


def _check_stopped(out: Path, address: str, stdout: str, stderr: str, code: int) -> int:
    """The session ended on a LinkError naming the scheduler (status 2): the runs done kept, once each,
    none recorded failed for the workers' absence. Returns the runs on disk."""
    assert code == 2, (code, stdout, stderr[-3000:])
    assert "Traceback" not in stderr, stderr[-3000:]
    assert f"{address}: no worker for 3 s" in stderr, stderr[-3000:]
    on_disk = _indices_written(out)
    assert len(on_disk) == len(set(on_disk)) < RUNS_ASKED, on_disk
    assert f"{RUNS_ASKED - len(on_disk)} runs not run: the same command again runs them" in stderr, stderr
    if on_disk:
        assert read_runs(out).ok.all() and not read_runs(out).errors
    return len(on_disk)


def _indices_written(out: Path) -> list[int]:
    """Every row's index in runs.csv as written (read_runs keeps the last row of an index: a run written
    twice would not show there)."""
    path = out / RUNS
    return [int(line.split(",", 1)[0]) for line in path.read_text().splitlines()[1:]] if path.exists() else []


def _resume_finishes(scenario: Path, out: Path) -> None:
    resumed = _montecarlo(scenario, out, "--workers", "1")
    _, stderr = _finish(resumed, 240.0)
    assert resumed.returncode == 0, stderr[-3000:]
    index = _indices_written(out)
    assert sorted(index) == list(range(RUNS_ASKED)), index  # every run once


@pytest.mark.parametrize("seed", [11, 12])
def test_every_worker_killed_at_a_drawn_moment_ends_the_campaign_naming_the_scheduler(tmp_path, seed):
    rng = random.Random(seed)
    after_rows, then_s = rng.randint(0, 3), rng.uniform(0.0, 0.4)  # the moment: rows on disk, then a delay
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mc"
    cluster = _Cluster(tmp_path, dask_env())
    proc = _montecarlo(scenario, out, "--scheduler", cluster.address)
    try:
        deadline = time.monotonic() + 120.0
        while _rows(out) < after_rows and proc.poll() is None:
            assert time.monotonic() < deadline
            time.sleep(0.02)
        time.sleep(then_s)
        # at most 3 of the 6 runs on disk and 0.4 s: the rest, a second or more each, are still to run
        assert proc.poll() is None, "the campaign ended before its worker was killed"
        cluster.kill_worker()
        stdout, stderr = _finish(proc, 90.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        cluster.close()
    _check_stopped(out, cluster.address, stdout, stderr, proc.returncode)
    _resume_finishes(scenario, out)


def test_a_worker_whose_python_lacks_hil_is_an_error_not_a_hang(tmp_path):
    """The worker's Python finds a ``hil`` that is not vscmg-hil's first on its path (as one without it
    installed fails to import it): unpickling the campaign's task breaks its stream and the worker closes."""
    shadow = tmp_path / "shadow" / "hil"
    shadow.mkdir(parents=True)
    (shadow / "__init__.py").write_text('raise ModuleNotFoundError("No module named \'hil\'", name="hil")\n')
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mc"
    cluster = _Cluster(tmp_path, dask_env(PYTHONPATH=str(shadow.parent)))
    proc = _montecarlo(scenario, out, "--scheduler", cluster.address)
    try:
        stdout, stderr = _finish(proc, 90.0)
    finally:
        cluster.close()
    assert _check_stopped(out, cluster.address, stdout, stderr, proc.returncode) == 0


def test_a_scheduler_without_a_worker_from_the_start_is_an_error_not_a_hang(tmp_path):
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mc"
    cluster = _Cluster(tmp_path, None)
    proc = _montecarlo(scenario, out, "--scheduler", cluster.address)
    try:
        stdout, stderr = _finish(proc, 90.0)
    finally:
        cluster.close()
    assert _check_stopped(out, cluster.address, stdout, stderr, proc.returncode) == 0


@pytest.mark.parametrize(
    ("value", "seconds"), [(None, 60.0), ("90s", 90.0), ("5 minutes", 300.0), (2, 2.0), ("abc", None),
                           ("-1s", None), (0, None), ("nan", None)],
)  # fmt: skip
def test_the_wait_for_a_worker_is_dasks_setting_or_an_error_naming_it(value, seconds):
    import dask

    from hil.montecarlo.campaign import NO_WORKERS_S, _no_workers_s
    from protocol.errors import ConfigError

    assert NO_WORKERS_S == 60.0
    with dask.config.set({"distributed.scheduler.no-workers-timeout": value}):
        if seconds is None:
            with pytest.raises(ConfigError) as info:
                _no_workers_s()
            assert info.value.where == "distributed.scheduler.no-workers-timeout"
        else:
            assert _no_workers_s() == seconds
