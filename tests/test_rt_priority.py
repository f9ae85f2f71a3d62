"""A real-time run under Linux's SCHED_FIFO (``hil run --rt-priority N``, :mod:`hil.timing.priority`): the
run's threads and the board it spawns inherit the policy, the summary says what the run had, and a run that
may not have it, or does not wait for the wall clock, is refused before it starts."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import threading

import pytest

from hil.timing.priority import current, realtime
from protocol.errors import ConfigError

PRIORITY = 10


def _may_use_fifo() -> bool:
    soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    return os.geteuid() == 0 or soft == resource.RLIM_INFINITY or soft >= PRIORITY


FIFO = pytest.mark.skipif(
    not _may_use_fifo(), reason="SCHED_FIFO needs root, CAP_SYS_NICE or ulimit -r >= 10 (CI runs as root)"
)


def test_no_priority_leaves_the_scheduling_as_it_is():
    before = current()
    with realtime(None) as had:
        assert had == before == current()
    assert before.policy in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH", "SCHED_IDLE")


@pytest.mark.parametrize("priority", [0, -1, 100, 10_000])
def test_a_priority_out_of_range_is_refused_naming_the_option(priority):
    with pytest.raises(ConfigError, match=r"run --rt-priority.*from 1 to 99"):
        with realtime(priority):
            pass


@FIFO
def test_a_thread_running_before_the_block_is_switched_too_and_switched_back():
    """A ground station's server thread starts before the run: left at the normal policy it would hold the
    interpreter's lock while a browser keeps it off the core."""
    ask, told = threading.Event(), []
    done = threading.Event()
    normal = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)

    def server() -> None:
        while not done.is_set():
            if ask.wait(0.01):
                ask.clear()
                told.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

    worker = threading.Thread(target=server)
    worker.start()
    try:
        with realtime(PRIORITY):
            ask.set()
            while len(told) < 1:
                worker.join(0.01)
        ask.set()
        while len(told) < 2:
            worker.join(0.01)
    finally:
        done.set()
        worker.join()
    assert told == [(os.SCHED_FIFO, PRIORITY), normal]


@FIFO
def test_threads_and_processes_started_inside_inherit_it_and_it_ends_with_the_block():
    before = current()
    seen: list[tuple[int, int]] = []
    with realtime(PRIORITY) as had:
        assert (
            (had.policy, had.priority) == ("SCHED_FIFO", PRIORITY) == (current().policy, current().priority)
        )
        worker = threading.Thread(
            target=lambda: seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))
        )
        worker.start()
        worker.join()
        child = subprocess.run(
            [
                sys.executable,
                "-c",
                "import os; print(os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)",
            ],
            capture_output=True,
            text=True,
            check=True,
        )
    assert seen == [(os.SCHED_FIFO, PRIORITY)]
    assert child.stdout.split() == [str(os.SCHED_FIFO), str(PRIORITY)]
    assert current() == before


def test_a_process_without_the_privilege_is_refused_with_what_to_do():
    """As an unprivileged user whose real-time limit is 0 (a default desktop account): the error names the
    remedies and the limit, and nothing changed."""
    script = f"""
import os, resource
from hil.timing.priority import current, realtime
from protocol.errors import ConfigError
if os.geteuid() == 0:
    os.setgroups([])
    os.setresgid(65534, 65534, 65534)
    os.setresuid(65534, 65534, 65534)
resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
before = current()
try:
    with realtime({PRIORITY}):
        print("granted")
except ConfigError as exc:
    print(exc)
assert current() == before
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    said = done.stdout
    assert "granted" not in said
    assert f"SCHED_FIFO priority {PRIORITY} is not permitted here" in said, said
    assert "CAP_SYS_NICE" in said and "ulimit -r: now 0" in said and "run --rt-priority" in said, said


def test_a_lockstep_run_refuses_a_real_time_priority(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--rt-priority", "10", "--no-plots", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert "run --rt-priority" in done.stderr and "lockstep" in done.stderr, done.stderr
    assert not list(tmp_path.iterdir())  # refused before a run directory was made


@FIFO
def test_a_real_time_run_says_it_ran_under_sched_fifo(tmp_path, phone_port):
    """``hil run --port spawn://...`` with ``--rt-priority``: its summary records the policy, and the run is
    an ordinary one otherwise (the stand-in phone at rest: no phone needed to reach the board and end)."""
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--port", "spawn://firmware-sim?units=4&world=cubesat-1u"
         f"&phone=udp://127.0.0.1:{phone_port}", "--phone", f"127.0.0.1:{phone_port}", "--rt-priority",
         str(PRIORITY), "--duration", "0.5", "--no-plots", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    summary = json.loads(next(tmp_path.glob("*/summary.json")).read_text())
    assert summary["scheduling"] == {"policy": "SCHED_FIFO", "priority": PRIORITY}, done.stderr
    assert summary["mode"] == "port" and done.returncode in (0, 1), done.stderr
    assert summary["tasks"]["control"]["runs"] > 10
