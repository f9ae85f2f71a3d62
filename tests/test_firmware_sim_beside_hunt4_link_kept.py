"""``firmware-sim --link PATH`` keeps PATH pointing at its pty while it serves (its help: "keep a symlink
at PATH pointing at the pty"), through the real command in a subprocess and a real host through the link.

Beside the tested path (the link made at start, removed at the end): a link removed while the board
served — by hand, by a cleaner of /tmp, by another ``firmware-sim --link PATH`` that took it and then
exited — was never made again, and a host reconnecting through it never found the board, which went on
serving behind a path that no longer existed, saying nothing.
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

from firmware_sim.servers.pty_server import LINK_CHECK_S


def _spawn(link: Path) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--link", str(link), "--units", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/"), path
    return proc, path


def _until(condition, timeout_s: float) -> bool:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def _stop(proc: subprocess.Popen[str]) -> str:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return err


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pauses=st.lists(st.floats(0.0, 0.8), min_size=1, max_size=3))
def test_a_link_removed_while_serving_is_made_again_and_reaches_the_board(tmp_path, pauses):
    link = tmp_path / f"board-{time.monotonic_ns()}"
    proc, path = _spawn(link)
    try:
        for pause in pauses:  # removed at drawn moments, however often
            time.sleep(pause)
            link.unlink()
            assert _until(link.is_symlink, 4 * LINK_CHECK_S + 2.0), "the link was never made again"
            assert os.readlink(link) == path
            host = SerialHost(str(link))  # a host reconnecting through it finds the board
            host.handshake()
            host.close()
    finally:
        err = _stop(proc)
    assert proc.returncode == 0, err
    assert "was removed while serving; it points at" in err
    assert not link.is_symlink()


def test_a_link_another_server_took_is_left_to_it(tmp_path):
    link = tmp_path / "board"
    proc, path = _spawn(link)
    try:
        os.unlink(link)
        os.symlink("/dev/null", link)  # another server's now
        time.sleep(3 * LINK_CHECK_S)
        assert os.readlink(link) == "/dev/null"
    finally:
        err = _stop(proc)
    assert proc.returncode == 0, err
    assert os.readlink(link) == "/dev/null"  # not removed at the end either: not ours
    assert "no longer points at" in err
