"""Campaigns under faults at drawn moments, beside the path the other campaign tests walk: the output
directory refusing a write after every run has finished (a full disk or a directory where summary.json,
its temporary or plots/ should be), figures of any finished runs (metrics equal up to rounding, or near
the largest float), a second Ctrl-C while the command closes its cluster, a worker process stopped
(SIGSTOP) at a drawn moment, the same command started twice on one directory. Each ends with a typed
error naming the file, an interrupt's status, or a loss reported and its runs rerun — never a traceback,
a hang, a run lost or written twice.

Real clusters throughout: in-process threads where nothing needs a process, a LocalCluster of worker
processes (and ``hil montecarlo`` in its own process) where a process must be signalled. Runs are the
short scenario of tests/montecarlo_support.py (~0.3 s of CPU each).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import logging
import os
import resource
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.cli import main as hil_main
from hil.montecarlo import Campaign, open_client, parse_dispersions, read_runs, run_campaign
from hil.montecarlo.dask_logs import quiet_interrupted_sync, quiet_scheduler_loss
from hil.montecarlo.metrics import METRICS, TRACES
from hil.montecarlo.plots import plot_campaign
from hil.montecarlo.runner import RunResult
from hil.montecarlo.store import RUNS, ResultStore
from hil.runtime.runlog import SUMMARY
from hil.scenario import load_scenario
from hil.scenario.paths import ROOT
from protocol.errors import HilError

INERTIA = '[spacecraft]\ninertia_scale = { dist = "normal", sigma = 0.05 }\n'


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory) -> Path:
    return write_quick_scenario(tmp_path_factory.mktemp("scenario"))


@pytest.fixture(scope="module")
def scenario(scenario_file):
    return load_scenario(scenario_file)


@pytest.fixture(scope="module")
def dispersion_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("dispersions") / "inertia.toml"
    path.write_text(INERTIA)
    return path


def _row_indices(out: Path) -> list[int]:
    """The run index of every row of runs.csv, duplicates kept."""
    with open(out / RUNS, newline="") as f:
        return [int(row[0]) for row in list(csv.reader(f))[1:]]


# --------------------------------------------------------------------------- the last files refused
def _cli(scenario_file: Path, dispersions: Path, out: Path, scheduler: str, *more: str) -> int:
    argv = ["montecarlo", str(scenario_file), "--runs", "2", "--seed", "4", "--dispersions", str(dispersions),
            "--scheduler", scheduler, "--out", str(out), *more]  # fmt: skip
    return hil_main(argv)


@pytest.mark.parametrize(
    ("block", "named", "plots"),
    [
        (lambda out: (out / "plots").write_text("not a directory"), "plots", True),
        (lambda out: (out / "plots" / "histograms.png").mkdir(parents=True), "plots/histograms.png", True),
        (lambda out: (out / SUMMARY).mkdir(), SUMMARY, False),
    ],
    ids=["plots-a-file", "a-plot-a-directory", "summary-a-directory"],
)  # (a directory where summary.json.tmp was: each writer's temporary has a name of its own now)
def test_a_summary_or_plot_the_directory_refuses_is_an_error_naming_it(
    scenario_file, dispersion_file, tmp_path, capsys, block, named, plots
):
    """Before: every run finished and on disk, then summary.json or a plot could not be written, and the
    command ended in an OSError's traceback (FileExistsError, IsADirectoryError). Now: status 2 and one
    line naming the file; the runs stay on disk, and once the obstacle is gone the same command runs
    nothing again and finishes."""
    from distributed import LocalCluster

    out = tmp_path / "mc"
    out.mkdir()
    block(out)
    extra = () if plots else ("--no-plots",)
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address="127.0.0.1:0"
    ) as cluster:
        assert _cli(scenario_file, dispersion_file, out, cluster.scheduler_address, *extra) == 2
        err = capsys.readouterr().err
        said = [line for line in err.splitlines() if line.startswith("hil montecarlo: error: ")]
        assert len(said) == 1 and f"{out / named}" in said[0] and "Traceback" not in err
        assert sorted(_row_indices(out)) == [0, 1]
        for path in sorted(out.rglob("*"), reverse=True):  # the obstacle cleared, the runs kept
            if path.name not in ("campaign.json", RUNS, "traces.bin"):
                path.rmdir() if path.is_dir() else path.unlink()
        assert _cli(scenario_file, dispersion_file, out, cluster.scheduler_address, *extra) == 0
        assert "2 runs were already in" in capsys.readouterr().err
    assert sorted(_row_indices(out)) == [0, 1]  # nothing ran twice
    assert json.loads((out / SUMMARY).read_text())["runs"] == 2


def test_a_disk_full_when_the_summary_is_written_is_an_error_naming_it(scenario, tmp_path):
    """The disk fills (here the file-size limit: EFBIG, as ENOSPC) right after the last run is on disk:
    writing summary.json was an OSError out of run_campaign; it is one of the project's errors naming
    summary.json, and every run is in runs.csv once."""
    campaign = Campaign(scenario, parse_dispersions(INERTIA, scenario), runs=3, seed=2, batch=3)
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)

    def fill_the_disk_after_the_last(result, done, total):
        if done == total:
            resource.setrlimit(resource.RLIMIT_FSIZE, (64, hard))

    try:
        with open_client(workers=1, processes=False) as client:
            with pytest.raises(HilError, match="cannot write") as info:
                run_campaign(campaign, tmp_path, client, on_result=fill_the_disk_after_the_last, plots=False)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert str(tmp_path / SUMMARY) in str(info.value)
    assert sorted(_row_indices(tmp_path)) == [0, 1, 2] and read_runs(tmp_path).ok.all()


# --------------------------------------------------------------------------- figures of any finished runs
def _nearly_equal(base: float, steps: list[int]) -> list[float]:
    """``base`` and values a few ulps from it: a metric equal in every run up to rounding."""
    return [float(base + k * np.spacing(base)) for k in steps]


def _column(n: int) -> st.SearchStrategy[list[float]]:
    """``n`` values of one column: any floats, or ``n`` nearly equal ones."""
    return st.one_of(
        st.lists(st.floats(), min_size=n, max_size=n),
        st.builds(
            _nearly_equal,
            st.floats(allow_nan=False, allow_infinity=False, min_value=-1e300, max_value=1e300),
            st.lists(st.integers(-3, 3), min_size=n, max_size=n),
        ),
    )


@st.composite
def _finished_runs(draw: st.DrawFn) -> tuple[dict[str, list[float]], float]:
    """1..6 ok runs: each metric's and the dispersed parameter's values (see :func:`_column`) and the
    level of every trace sample."""
    n = draw(st.integers(1, 6))
    columns = {name: draw(_column(n), label=name) for name in (*METRICS, "inertia_scale")}
    return columns, draw(st.floats(width=32), label="trace level")


ONE_ULP_APART = {name: [1.0, 2.0] for name in METRICS} | {
    "peak_error_deg": [19.99999999999998, 19.999999999999982],
    "inertia_scale": [0.97, 1.01],
}
NEAR_THE_LARGEST_FLOAT = {name: [0.0] for name in METRICS} | {
    "peak_tracking_deg": [8.98846568686832e307],  # 2**1023: matplotlib's tick locator looped for ever
    "final_error_deg": [-1.7e308],
    "inertia_scale": [1.7e308],
}


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(runs=_finished_runs())
@example(runs=(ONE_ULP_APART, 1.0))
@example(runs=(NEAR_THE_LARGEST_FLOAT, 1.0))
def test_the_figures_of_any_finished_runs_are_drawn(scenario, tmp_path_factory, runs):
    """Whatever the runs' metrics and parameters (nearly equal in every run, huge, inf, NaN) and traces,
    the figures are drawn. Before: two runs whose ``peak_error_deg`` differed by one ulp (the slew's
    angle, 19.99999999999998 and 19.999999999999982: met by a real campaign with no manoeuvre
    dispersion) ended the campaign, and `hil report`, in numpy's ValueError "Too many bins for data
    range" after the last run. A value near the largest float (only an edited runs.csv says so, for `hil
    report`) is left out and counted: matplotlib's tick locator looped for ever on such an axis."""
    columns, level = runs
    n = len(columns["inertia_scale"])
    campaign = Campaign(scenario, parse_dispersions(INERTIA, scenario), runs=n, seed=1)
    out = tmp_path_factory.mktemp("figures")
    samples = int(campaign.manifest()["trace_samples"])
    with ResultStore(out, campaign.manifest()) as store:
        for i in range(n):
            drawn = {f"spacecraft.inertia_scale.{a}": columns["inertia_scale"][i] for a in "xyz"}
            metrics = {name: columns[name][i] for name in METRICS}
            trace = np.full((len(TRACES), samples), level, dtype=np.float32)
            store.append(RunResult(i, True, drawn, metrics, trace))
    drawn_plots = plot_campaign(out, scenario.settle_deg, scenario.spacecraft.limits.max_gimbal_rate)
    assert "histograms" in drawn_plots and drawn_plots["histograms"].stat().st_size > 0


# --------------------------------------------------------------------------- Ctrl-C pressed twice
def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


def _left_in_session(sid: int, within_s: float = 10.0) -> list[str]:
    """The live processes of session ``sid`` (zombies aside: already dead, waiting for their reaper) still
    there ``within_s`` after asking: a worker whose nanny has just closed may take a moment to exit (seen as
    ``[python]``, its memory already released, on a loaded machine)."""
    deadline = time.monotonic() + within_s
    while True:
        ps = subprocess.run(["ps", "-o", "pid=,stat=,args=", "-s", str(sid)], capture_output=True, text=True)
        live = [line for line in ps.stdout.splitlines() if line.split()[1:2] != ["Z"] and line.strip()]
        if not live or time.monotonic() > deadline:
            return live
        time.sleep(0.1)


@settings(max_examples=1, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(after_rows=st.integers(1, 3), gap_s=st.floats(0.02, 0.25))
@example(after_rows=2, gap_s=0.1)
def test_ctrl_c_twice_ends_the_command_at_once_with_its_runs_on_disk(
    scenario_file, dispersion_file, tmp_path_factory, after_rows, gap_s
):
    """`hil montecarlo` on a LocalCluster of worker processes gets Ctrl-C (SIGINT to its process group)
    after a drawn number of rows, then a second one a drawn moment later, as a user pressing it twice.
    Before: the second came while the first's cluster close was under way, threw it away half done, and
    the command said "interrupted" and then sat 10 s more in Dask's exit hook closing the half-closed
    cluster. Now the second is held until the close is done: the command ends within seconds, status 130
    (or the signal's own, if the second lands as the interpreter exits), its finished runs on disk once,
    no process left behind."""
    out = tmp_path_factory.mktemp("twice") / "mc"
    cmd = [sys.executable, "-m", "hil", "montecarlo", str(scenario_file), "--runs", "12", "--seed", "6",
           "--dispersions", str(dispersion_file), "--workers", "2", "--batch", "1", "--out", str(out),
           "--no-plots"]  # fmt: skip
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and _rows(out) < after_rows:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.01)
        os.killpg(proc.pid, signal.SIGINT)
        first = time.monotonic()
        time.sleep(gap_s)
        with contextlib.suppress(ProcessLookupError):  # already gone: nothing to press twice
            os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        took = time.monotonic() - first
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode in (130, -signal.SIGINT), err
    assert "hil montecarlo: interrupted (SIGINT)" in err and "Traceback" not in err
    # The fault sat 10 s in Dask's exit hook after its close (its fixed timeout): anything from 10 s on.
    # Fixed, it ends in ~1 s, ~2.6 s on a loaded 2-core machine; 9.5 s keeps both apart there.
    assert took < 9.5, f"the command took {took:.1f} s to end after Ctrl-C"
    assert not _left_in_session(proc.pid)
    rows = _row_indices(out)
    assert len(rows) >= after_rows and len(set(rows)) == len(rows) and read_runs(out).dropped == 0


# --------------------------------------------------------------------------- a worker process stopped
STOPPED_FOR_AT_MOST_S = 30.0
"""How long a test leaves a worker stopped before it continues it (and fails): Dask's default heartbeat
TTL of 5 minutes held the campaign that long and more."""


@pytest.fixture(scope="module")
def stoppable_cluster():
    """Two worker processes whose scheduler restarts a worker silent for 5 s (10 heartbeats: Dask's
    floor; the TTL asked for is 1 s), so that a stopped one is replaced within seconds."""
    with open_client(workers=2, worker_ttl_s=1.0) as client:
        yield client


def _worker_with_our_work(client) -> str | None:
    """A worker running a chunk, else one holding a chunk's result unread; None if no worker has any."""
    processing = {w: keys for w, keys in client.processing().items() if keys}
    if processing:
        return max(processing, key=lambda w: len(processing[w]))
    holding = [w for w, keys in client.has_what().items() if keys]
    return holding[0] if holding else None


@pytest.mark.parametrize("error", [ConnectionResetError("Stream is closed"), ValueError("a real fault")])
def test_a_workers_lost_scheduler_is_one_line_and_any_other_fault_keeps_its_traceback(error):
    """The worker preload's filter (``quiet_scheduler_loss``): a heartbeat that finds the scheduler gone
    (an OSError: the campaign closing, e.g. Ctrl-C twice) is logged as distributed logs it, on one line
    naming the error, without the traceback CI once caught on the user's terminal after "interrupted";
    any other exception is logged with its traceback, as before."""
    worker_log = logging.getLogger("distributed.worker")
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    worker_log.addHandler(handler)
    filters = list(worker_log.filters)
    try:
        quiet_scheduler_loss()
        quiet_scheduler_loss()  # once, however often a worker's preload runs
        assert len(worker_log.filters) == len(filters) + 1
        try:
            raise error
        except Exception:
            worker_log.exception("Failed to communicate with scheduler during %s.", "heartbeat")
    finally:
        worker_log.removeHandler(handler)
        worker_log.filters[:] = filters
    text = stream.getvalue()
    assert text.startswith("Failed to communicate with scheduler during heartbeat.")
    if isinstance(error, OSError):
        assert "Traceback" not in text and "Stream is closed" in text and text.count("\n") == 1, text
    else:
        assert "Traceback (most recent call last)" in text and "a real fault" in text, text


def _interrupt_a_call_not_yet_begun() -> list[logging.LogRecord]:
    """distributed's blocking ``sync`` interrupted (a KeyboardInterrupt raised in the main thread, as hil's
    SIGINT handler raises it) while its event loop is busy, so before the call has begun; returns what
    tornado's ``tornado.application`` logger let through meanwhile (every level)."""
    from distributed.utils import LoopRunner, sync

    log = logging.getLogger("tornado.application")
    records: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = records.append  # type: ignore[method-assign]
    handler.filter = lambda record: all(f.filter(record) for f in log.filters)  # type: ignore[method-assign]
    log.addHandler(handler)
    runner = LoopRunner(asynchronous=False)
    runner.start()
    busy, ran = threading.Event(), threading.Event()

    async def the_call() -> None:
        ran.set()

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGUSR1, interrupt)
    try:
        runner.loop.add_callback(busy.wait, 10.0)  # the loop held: the call cannot begin
        threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGUSR1)).start()
        with pytest.raises(KeyboardInterrupt):
            sync(runner.loop, the_call)
        busy.set()
        assert ran.wait(10.0)  # the loop went on to the call, and to distributed's cancel of it, before it
        done = threading.Event()
        runner.loop.add_callback(done.set)
        assert done.wait(10.0)
    finally:
        busy.set()
        signal.signal(signal.SIGUSR1, previous)
        runner.stop()
        log.removeHandler(handler)
    return [r for r in records if r.levelno >= logging.ERROR]


def test_a_call_interrupted_before_it_began_leaves_no_traceback_and_other_callback_faults_keep_theirs():
    """The driver's filter (``quiet_interrupted_sync``). Ctrl-C landing in one of the client's blocking
    calls before Dask's event loop had begun it made distributed's own cancel of it fail (a NameError on
    its unbound ``future``), and tornado logged that with its traceback: CI caught it on the user's
    terminal beside "interrupted" for Ctrl-C pressed twice. Reproduced here on distributed's own ``sync``
    and loop: without the filter the record is there (the fault the filter is for), with it none is; a
    callback failing otherwise, a NameError too, keeps its record and traceback."""
    log = logging.getLogger("tornado.application")
    filters = list(log.filters)
    try:
        log.filters[:] = [f for f in filters if type(f).__name__ != "_InterruptedSyncUntraced"]
        unfiltered = _interrupt_a_call_not_yet_begun()
        assert [type(r.exc_info[1]).__name__ for r in unfiltered if r.exc_info] == ["NameError"], unfiltered
        quiet_interrupted_sync()
        quiet_interrupted_sync()  # once
        assert (
            len(log.filters)
            == len([f for f in filters if type(f).__name__ != "_InterruptedSyncUntraced"]) + 1
        )
        assert _interrupt_a_call_not_yet_begun() == []
        try:
            undefined_name  # noqa: B018, F821 — a NameError of another callback
        except NameError:
            record = log.makeRecord(
                log.name, logging.ERROR, __file__, 0, "Exception in callback", (), sys.exc_info()
            )
        assert all(f.filter(record) for f in log.filters) and record.exc_info is not None
    finally:
        log.filters[:] = filters


@settings(max_examples=1, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(after=st.integers(1, 4))
@example(after=4)
def test_a_worker_stopped_at_a_drawn_moment_is_replaced_and_its_runs_land_once(
    scenario, stoppable_cluster, tmp_path_factory, after
):
    """SIGSTOP to the worker process running a chunk (or, after the last run, holding the last chunk's
    result), at a drawn result. Before: nothing noticed a stopped worker for Dask's heartbeat TTL, 5 to
    10 minutes, with the campaign waiting on it; and one stopped holding the last chunk's result held
    the driver's read of it until Dask reran it, its loss queued meanwhile and never counted. Now the
    LocalCluster's scheduler restarts a worker silent for :data:`WORKER_TTL_S`: the campaign finishes in
    seconds, the loss is reported once and counted in summary.json, every run lands once."""
    client = stoppable_cluster
    client.wait_for_workers(2, timeout=60)  # the worker an earlier example stopped is back
    campaign = Campaign(scenario, parse_dispersions(INERTIA, scenario), runs=4, seed=after, batch=2)
    out = tmp_path_factory.mktemp("stopped")
    stopped: list[tuple[str, int]] = []
    losses = []

    def stop_a_worker(result, done, total):
        if done != after:
            return
        worker = _worker_with_our_work(client)
        assert worker is not None, "no worker has this campaign's work"
        pid = client.run(os.getpid, workers=[worker])[worker]
        os.kill(pid, signal.SIGSTOP)
        stopped.append((worker, pid))
        threading.Timer(STOPPED_FOR_AT_MOST_S, _continue, [pid]).start()

    start = time.monotonic()
    try:
        report = run_campaign(
            campaign, out, client, on_result=stop_a_worker, on_worker_lost=losses.append, plots=False
        )
    finally:
        for _, pid in stopped:
            _continue(pid)
    took = time.monotonic() - start
    assert took < STOPPED_FOR_AT_MOST_S, f"the campaign waited {took:.0f} s on a stopped worker"
    assert [loss.worker for loss in losses] == [stopped[0][0]]
    assert report.workers_lost == 1 and json.loads((out / SUMMARY).read_text())["workers_lost"] == 1
    assert sorted(_row_indices(out)) == [0, 1, 2, 3] and read_runs(out).ok.all()
    assert report.completed == 4 and report.failed == 0


def _continue(pid: int) -> None:
    """SIGCONT to ``pid`` if it is still there (its nanny may have killed it already)."""
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGCONT)


# --------------------------------------------------------------------------- the same command twice at once
def test_a_second_session_on_a_directory_being_written_is_refused(
    scenario_file, dispersion_file, tmp_path, capsys
):
    """`hil montecarlo` writing a campaign (its own process), and the same command started again on the
    same directory meanwhile (another terminal). Before: the second ran every run the directory lacked
    when it started — runs the first was running too — so runs.csv held them twice (counted as dropped
    lines) and both sessions said they had run them. Now the second is refused, status 2, naming the
    directory, and writes nothing; the first finishes with every run once, and once it has ended the
    same command finds the campaign complete."""
    from distributed import LocalCluster

    out = tmp_path / "mc"
    first = [sys.executable, "-m", "hil", "montecarlo", str(scenario_file), "--runs", "12", "--seed", "8",
             "--dispersions", str(dispersion_file), "--workers", "1", "--batch", "1", "--out", str(out),
             "--no-plots"]  # fmt: skip
    with LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address="127.0.0.1:0"
    ) as cluster:
        again = ["montecarlo", str(scenario_file), "--runs", "12", "--seed", "8", "--dispersions",
                 str(dispersion_file), "--scheduler", cluster.scheduler_address, "--out", str(out),
                 "--no-plots"]  # fmt: skip
        proc = subprocess.Popen(
            first, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
        )
        try:
            deadline = time.monotonic() + 60.0
            while time.monotonic() < deadline and _rows(out) < 1:
                assert proc.poll() is None, proc.communicate()
                time.sleep(0.01)
            assert hil_main(again) == 2
            assert proc.poll() is None, "the first session ended before the second tried"
            err = capsys.readouterr().err
            assert f"hil montecarlo: error: {out}: another session is writing" in err
            _, first_err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        assert proc.returncode == 0, first_err
        assert sorted(_row_indices(out)) == list(range(12))  # every run once
        assert json.loads((out / SUMMARY).read_text())["dropped_lines"] == 0
        assert hil_main(again) == 0  # the lock went with the first session
        assert "12 runs were already in" in capsys.readouterr().err
    assert sorted(_row_indices(out)) == list(range(12))
