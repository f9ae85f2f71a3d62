"""``firmware-sim --avr`` whose ``avr-harness`` runs but does not answer for a while: stopped (SIGSTOP, a
debugger), or not given the CPU on a machine busy with something else.

The harness serves the pty itself; firmware-sim only watches it through its control pipe every 50 ms. A
harness that had not answered one look within the control pipe's answer timeout (10 s) ended
firmware-sim with a ``LinkTimeout`` traceback and status 1, and firmware-sim's exit took the board down
with it — a board that was only paused. And the late answer, had anything gone on reading the pipe,
would have been taken for the next command's. Now the pause is said once, the board is watched on, the
late answers are dropped in order, and its return is said; the board answers a host again.
Real processes, a real pty; the signals go to the harness's process, never to pytest's.
"""

from __future__ import annotations

import os
import random
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conformance.host import SerialHost

from firmware_sim.avr.harness import _ANSWER_TIMEOUT_S

pytestmark = pytest.mark.firmware

DEADLINE_S = 30.0


def _harness_of(parent: int) -> int:
    """The pid of the ``avr-harness`` whose parent is ``parent`` (waits for it)."""
    end = time.monotonic() + DEADLINE_S
    while time.monotonic() < end:
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit():
                continue
            try:
                comm = (entry / "comm").read_text().strip()
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            if comm == "avr-harness" and ppid == parent:
                return int(entry.name)
        time.sleep(0.05)
    raise AssertionError(f"no avr-harness child of {parent} within {DEADLINE_S} s")


@pytest.mark.parametrize("seed", [0, 1])
def test_a_harness_that_stops_answering_for_a_while_is_watched_on_not_a_traceback(tmp_path, seed):
    link = tmp_path / "board"
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--avr", "--units", "2", "--link", str(link)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    harness = None
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], DEADLINE_S)
        assert ready, "no pty path"
        path = proc.stdout.readline().strip()
        harness = _harness_of(proc.pid)
        time.sleep(random.Random(seed).uniform(0.0, 1.0))  # a drawn moment of the watcher's loop
        os.kill(harness, signal.SIGSTOP)
        time.sleep(_ANSWER_TIMEOUT_S + 2.0)  # longer than any one look may wait for its answer
        assert proc.poll() is None, proc.communicate()[1]  # firmware-sim watches on
        os.kill(harness, signal.SIGCONT)
        host = SerialHost(path)
        try:
            host.handshake(timeout=0.2, tries=50)  # the board serves again
        finally:
            host.close()
        time.sleep(0.5)  # a few looks after its return
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=DEADLINE_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if harness is not None and Path(f"/proc/{harness}").exists():
            os.kill(harness, signal.SIGCONT)  # a failed test's stopped harness: let it read its end of file
    assert "Traceback" not in err, err
    assert proc.returncode == 0, err
    assert "runs but does not answer" in err and "answers again after" in err, err
    assert not link.is_symlink()  # stopped cleanly
