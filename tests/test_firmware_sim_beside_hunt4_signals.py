"""``firmware-sim`` stopped by SIGINT, SIGTERM or SIGHUP at drawn moments of its whole life, and on a
terminal that has closed — every scenario in a subprocess of the real command, with a real ``--link``.

Beside the tested path (SIGTERM / SIGINT once it serves): SIGHUP — the terminal it was started from
closed — killed it at any moment with its ``--link`` symlink left pointing at nothing; SIGINT during
start-up was a ``KeyboardInterrupt`` traceback and SIGTERM a kill (the link left if it was made); and
on a terminal that had closed, the status thread's write failed (EIO), its error then cut the clean-up
short: the symlink left, exit status 1.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from conformance.host import SerialHost
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _caught(pid: int) -> int:
    """The signals process ``pid`` has a handler for (``SigCgt`` of /proc/PID/status), as a bit mask."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return int(line.split()[1], 16)
    return 0


def _wait_for_main_module(proc: subprocess.Popen[str]) -> None:
    """Until ``python -m firmware_sim``'s own code runs: Python's SIGINT handler, once seen, replaced by
    the OS's default (``firmware_sim.__main__``), or SIGTERM caught (:func:`firmware_sim.cli.main`'s
    handlers). The moments before are the interpreter's own start-up, not the command's."""
    sigint, sigterm = 1 << (signal.SIGINT - 1), 1 << (signal.SIGTERM - 1)
    pythons_handler_seen = False
    deadline = time.monotonic() + 30.0
    while proc.poll() is None:
        caught = _caught(proc.pid)
        if caught & sigterm or (pythons_handler_seen and not caught & sigint):
            return
        pythons_handler_seen |= bool(caught & sigint)
        assert time.monotonic() < deadline, "firmware-sim never started"
        time.sleep(0.001)


def _spawn(link: Path, *extra: str, stderr: int = subprocess.PIPE) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--link", str(link), *extra],
        stdout=subprocess.PIPE, stderr=stderr, stdin=subprocess.DEVNULL, text=True,
    )  # fmt: skip


def _kill(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait()


@settings(max_examples=14, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    signum=st.sampled_from(STOP_SIGNALS),
    after_s=st.floats(0.0, 1.2),
    host=st.booleans(),
    world=st.sampled_from([False, False, False, True]),
)
def test_a_stop_signal_at_any_moment_ends_it_cleanly(tmp_path, signum, after_s, host, world):
    link = tmp_path / f"board-{os.getpid()}-{time.monotonic_ns()}"
    proc = _spawn(link, *(["--world", "cubesat-1u", "--phone", "udp://127.0.0.1:9"] if world else []))
    try:
        _wait_for_main_module(proc)
        deadline = time.monotonic() + after_s
        if host:  # a host on the pty when the signal comes, if the board serves by then
            assert proc.stdout is not None
            path = proc.stdout.readline().strip()
            if path:
                SerialHost(path).handshake()
        time.sleep(max(deadline - time.monotonic(), 0.0))
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        _kill(proc)
    assert "Traceback" not in err, err
    assert not link.is_symlink(), f"{signal.Signals(signum).name} left {link} -> {os.readlink(link)}"
    if proc.returncode != 0:  # only before firmware-sim's own handlers: nothing made, nothing said
        assert proc.returncode == -signum, (proc.returncode, err)
        assert "waiting for a host" not in err, err
    else:
        assert "firmware-sim: stopped;" in err, err


@settings(max_examples=4, deadline=None)
@given(signum=st.sampled_from([signal.SIGHUP, signal.SIGTERM]), host_left=st.booleans())
def test_on_a_terminal_that_closed_it_still_removes_its_link_and_ends_cleanly(
    tmp_path_factory, signum, host_left
):
    link = tmp_path_factory.mktemp("hup") / "board"
    master, slave = os.openpty()  # the terminal: its stderr, closed under it like a terminal window
    proc = _spawn(link, stderr=slave)
    os.close(slave)
    try:
        assert proc.stdout is not None
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/"), path
        time.sleep(0.2)
        os.close(master)  # writes to it now fail with EIO
        if host_left:  # a status line to say ("host connected", "host left") with nowhere to say it
            host = SerialHost(path)
            host.handshake()
            time.sleep(0.3)
            host.close()
            time.sleep(1.3)
        assert proc.poll() is None
        proc.send_signal(signum)
        assert proc.wait(timeout=30) == 0
    finally:
        _kill(proc)
    assert not link.is_symlink()
