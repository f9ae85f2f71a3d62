"""Drawing shared among forked processes (:mod:`hil.plots.forked`): results in order whatever the share, a
job's error raised as itself, a child that dies named, no fork beside another thread; and the plotter
process ``hil run`` starts draws, forked, the same bytes as one process does.

The forking checks run in a fresh interpreter: the test process may have threads of its own, and
``draw_shared`` rightly refuses to fork beside them."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from hil.plots.forked import draw_shared

REPO = Path(__file__).resolve().parents[1]


def _fresh(code: str) -> str:
    """``code`` run in a fresh interpreter of this environment: its stdout (it must exit 0)."""
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_every_share_gives_the_jobs_results_in_order_each_job_run_once():
    out = _fresh(
        """
        import os, time
        from functools import partial
        from hil.plots.forked import draw_shared

        def job(i):
            time.sleep(0.001)
            return (i * i, os.getpid())

        for n in (0, 1, 2, 5, 9, 40):
            for processes in (1, 2, 3, 4, 12):
                results = draw_shared([partial(job, i) for i in range(n)], processes)
                assert [r for r, _ in results] == [i * i for i in range(n)], (n, processes)
                pids = {pid for _, pid in results}
                assert len(pids) <= min(processes, n), (n, processes)
        print("ok")
        """
    )
    assert out.strip() == "ok"


def test_a_process_whose_jobs_are_slow_takes_fewer_of_them():
    """Each process takes the next job not taken: a process held by a slow job leaves the quick ones to
    the other (with fixed shares, every other job, each process would draw four of eight)."""
    out = _fresh(
        """
        import os, time
        from functools import partial
        from hil.plots.forked import draw_shared

        def job(i):
            time.sleep(0.6 if i == 0 else 0.05)
            return os.getpid()

        pids = draw_shared([partial(job, i) for i in range(8)], 2)
        print(sum(pid == pids[0] for pid in pids))
        """
    )
    assert out.strip() == "1"


def test_a_jobs_error_is_raised_as_itself_and_a_child_that_dies_is_named():
    out = _fresh(
        """
        import os, time
        from functools import partial
        from hil.plots.forked import draw_shared
        from protocol.errors import HilError, InputFormatError

        def fine(i):
            return i

        def bad(i):
            raise InputFormatError(f"job {i}: no such column", "telemetry.csv")

        me = os.getpid()

        def dies(i):
            if os.getpid() != me:  # a child (a job the parent takes runs as usual)
                os._exit(7)
            time.sleep(0.3)  # the child takes the next job meanwhile
            return i

        for where in (0, 1, 3):  # this process's share, then a child's
            jobs = [partial(fine, i) for i in range(4)]
            jobs[where] = partial(bad, where)
            try:
                draw_shared(jobs, 2)
            except InputFormatError as exc:
                assert f"job {where}: no such column" in str(exc) and exc.path == "telemetry.csv", exc
            else:
                raise AssertionError("no error")
        try:  # the parent takes job 0 (dies, which sleeps there), the child job 1 (dies, which exits)
            draw_shared([partial(dies, 0), partial(dies, 1)], 2)
        except HilError as exc:
            assert "exit status 7" in str(exc), exc
        else:
            raise AssertionError("a dead child went unnoticed")
        assert draw_shared([partial(fine, i) for i in range(3)], 2) == [0, 1, 2]
        try:  # every child reaped
            os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            pass
        else:
            raise AssertionError("a child left unreaped")
        print("ok")
        """
    )
    assert out.strip() == "ok"


def test_no_fork_while_another_thread_runs():
    import os
    import threading

    stop = threading.Event()
    helper = threading.Thread(target=stop.wait)
    helper.start()
    try:
        pids = draw_shared([os.getpid] * 4, 4)
    finally:
        stop.set()
        helper.join()
    assert pids == [os.getpid()] * 4


@pytest.mark.slow
def test_the_plotter_process_draws_the_same_figures_as_one_process(tmp_path):
    """A real run's directory drawn by ``python -m hil.cli._plotter`` (warmed by a figure it throws away,
    then forked, one process per core, at least two) and by :func:`plot_run` in one process: the same
    figures, byte for byte."""
    from hil.plots.run import plot_run
    from hil.runtime import RunOptions, run
    from hil.scenario import load_scenario

    scenario = load_scenario("cubesat-1u")
    result = run(scenario, RunOptions(out_root=tmp_path, duration_s=2.0))
    run_dir = result.run_dir
    assert run_dir is not None
    one = {name: path.read_bytes() for name, path in plot_run(run_dir).items()}
    for path in (run_dir / "plots").iterdir():
        path.unlink()
    done = subprocess.run(
        [sys.executable, "-c", "import sys; from hil.cli import _plotter; "
         "_plotter.available_cores = lambda: 2; sys.exit(_plotter.main())"],
        input=f"{run_dir}\n",
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    printed = dict(line.split(": ", 1) for line in done.stdout.splitlines())
    assert set(printed) == set(one) and len(one) == 9
    for name, data in one.items():
        assert Path(printed[name]).read_bytes() == data, name
