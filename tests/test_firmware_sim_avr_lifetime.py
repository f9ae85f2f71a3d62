"""``firmware-sim --avr`` and its ``avr-harness`` child live and die together (issue 25, finding 5).

Real processes on real ptys. A harness that outlived a SIGKILLed firmware-sim kept serving the pty, so a
restarted firmware-sim started a second board the host never noticed; a harness killed under
firmware-sim left it exiting 247 without a word, its ``--link`` symlink pointing at a pty number another
process may get next. Every wait is a deadline loop polling ``/proc`` or the exit status, generous enough
for a machine whose cores are busy with something else.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

pytestmark = pytest.mark.firmware

DEADLINE_S = 30.0
"""How long anything here may take: far beyond what it needs, so a loaded machine does not fail it."""

HARNESS_DIED = 3
"""firmware-sim's exit status when its harness dies under it (docs/firmware_sim.md)."""


def _stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent pid, start time) of a live process, None once it is gone (a zombie counts as gone:
    it serves nothing, and only its parent's reaping is left)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None if fields[0] in ("Z", "X") else (fields[0], int(fields[1]), int(fields[19]))


def _harness_of(parent: int) -> tuple[int, int]:
    """(pid, start time) of the ``avr-harness`` process whose parent is ``parent`` (waits for it)."""
    end = time.monotonic() + DEADLINE_S
    while time.monotonic() < end:
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit():
                continue
            try:
                comm = (entry / "comm").read_text().strip()
            except OSError:
                continue
            stat = _stat(int(entry.name)) if comm == "avr-harness" else None
            if stat is not None and stat[1] == parent:
                return int(entry.name), stat[2]
        time.sleep(0.05)
    raise AssertionError(f"no avr-harness child of {parent} within {DEADLINE_S} s")


def _gone(pid: int, started: int) -> bool:
    """The process that started at ``started`` no longer runs (its pid may have been reused since)."""
    stat = _stat(pid)
    return stat is None or stat[2] != started


def _until(condition: Callable[[], bool], what: str) -> None:
    end = time.monotonic() + DEADLINE_S
    while not condition():
        assert time.monotonic() < end, f"{what} not within {DEADLINE_S} s"
        time.sleep(0.05)


def _first_line(proc: subprocess.Popen[str]) -> str:
    """The first stdout line (the pty path), read against the deadline rather than blocking forever."""
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], DEADLINE_S)
    assert ready, f"no pty path within {DEADLINE_S} s"
    return proc.stdout.readline().strip()


@contextmanager
def _firmware_sim(tmp_path: Path, *extra: str) -> Iterator[tuple[subprocess.Popen[str], str, Path, Path]]:
    """``firmware-sim --avr --link`` with its own TMPDIR: (process, pty path, link, TMPDIR). Whatever is
    still running at the end (a failed test's) is killed by its pid."""
    link, tmp = tmp_path / "board", tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--avr", "--units", "2", "--link", str(link), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "TMPDIR": str(tmp)},
    )
    harness: tuple[int, int] | None = None
    try:
        path = _first_line(proc)
        assert path.startswith("/dev/pts/") and os.readlink(link) == path
        harness = _harness_of(proc.pid)
        yield proc, path, link, tmp
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        if harness is not None and not _gone(*harness):
            os.kill(harness[0], signal.SIGKILL)
        for stream in (proc.stdout, proc.stderr):
            assert stream is not None
            stream.close()


def test_a_sigkilled_firmware_sim_takes_its_harness_and_its_link_with_it(tmp_path):
    with _firmware_sim(tmp_path) as (proc, path, link, tmp):
        harness = _harness_of(proc.pid)
        proc.send_signal(signal.SIGKILL)  # no handler, no finally: only the kernel can tell the harness
        proc.wait()
        _until(lambda: _gone(*harness), "the harness ending after its firmware-sim was SIGKILLed")
        _until(lambda: not link.is_symlink(), "the harness removing its link")  # it stopped cleanly
        assert list(tmp.iterdir()) == []  # no temporary board directory left behind either


@pytest.mark.parametrize(
    ("sig", "how"),
    [(signal.SIGKILL, "killed by SIGKILL"), (signal.SIGTERM, "exited with status 0")],
    ids=["SIGKILL", "SIGTERM"],
)
def test_a_harness_that_dies_ends_firmware_sim_with_one_line_naming_it(tmp_path, sig, how):
    with _firmware_sim(tmp_path) as (proc, path, link, tmp):
        pid, _ = _harness_of(proc.pid)
        os.kill(pid, sig)
        _until(lambda: proc.poll() is not None, "firmware-sim exiting after its harness died")
        assert proc.returncode == HARNESS_DIED
        assert proc.stderr is not None
        err = proc.stderr.read()
        errors = [line for line in err.splitlines() if line.startswith("firmware-sim: error:")]
        assert errors == [f"firmware-sim: error: avr-harness (pid {pid}) {how}: the board on {path} is gone"]
        assert "Traceback" not in err, err
        assert not link.is_symlink()
        assert list(tmp.iterdir()) == []


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_stops_firmware_sim_avr_cleanly_with_everything_removed(tmp_path, sig):
    with _firmware_sim(tmp_path) as (proc, path, link, tmp):
        harness = _harness_of(proc.pid)
        proc.send_signal(sig)
        _until(lambda: proc.poll() is not None, "firmware-sim stopping on a signal")
        assert proc.returncode == 0
        assert _gone(*harness)
        assert not link.is_symlink()
        assert list(tmp.iterdir()) == []


def test_a_sigkilled_host_takes_its_spawned_avr_board_with_it(tmp_path):
    """The whole chain: the host dies, its spawn://firmware-sim (parent-death signal) stops, and the
    harness with it."""
    link = tmp_path / "board"
    host = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\n"
            "from hil.link.transports import open_transport\n"
            f"t = open_transport('spawn://firmware-sim?avr=&units=1&start_timeout=60&link={link}')\n"
            "print(t.pid, flush=True)\n"
            "time.sleep(600)\n",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    started: list[tuple[int, int]] = []  # firmware-sim, then its harness: killed at the end if running
    try:
        firmware_sim = int(_first_line(host))
        stat = _stat(firmware_sim)
        assert stat is not None
        started.append((firmware_sim, stat[2]))
        harness = _harness_of(firmware_sim)
        started.append(harness)
        host.send_signal(signal.SIGKILL)
        host.wait()
        _until(lambda: _gone(*harness), "the harness ending after the host was SIGKILLed")
        _until(lambda: not link.is_symlink(), "the link's removal")
    finally:
        if host.poll() is None:
            host.kill()
        host.wait()
        for pid, start in started:
            if not _gone(pid, start):
                os.kill(pid, signal.SIGKILL)
        assert host.stdout is not None
        host.stdout.close()


# --------------------------------------------------------------------------- the stepped firmware board
# With a world (``--avr --world``) or on a bus (``--avr --can``) the firmware is stepped from firmware-sim
# (firmware_sim.avr.stepped) behind its own server: the same lifetimes hold there.


def _where(kind: str, tmp_path: Path) -> list[str]:
    from bench.can_bus import multicast_url

    if kind == "can":
        return ["--can", multicast_url(fd=True)]
    return ["--world", "cubesat-1u", "--link", str(tmp_path / "board")]


@contextmanager
def _stepped(tmp_path: Path, kind: str) -> Iterator[tuple[subprocess.Popen[str], str, Path]]:
    """``firmware-sim --avr`` stepping the firmware (``kind``: "can" or "world"), in a session of its own
    (so a signal can go to its whole process group, as a terminal's Ctrl-C does): (process, what the host
    opens, TMPDIR)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    units = ["--units", "2"] if kind == "can" else []
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--avr", *units, *_where(kind, tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "TMPDIR": str(tmp)},
        start_new_session=True,
    )
    try:
        yield proc, _first_line(proc), tmp
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        for stream in (proc.stdout, proc.stderr):
            assert stream is not None
            stream.close()


@pytest.mark.udp_multicast
@pytest.mark.parametrize("kind", ["can", "world"])
def test_a_stepped_harness_that_dies_ends_firmware_sim_with_exit_3_and_one_error_line(tmp_path, kind):
    """It once ended in a traceback, exit 1 (the world's thread and the server both met the dead pipe)."""
    with _stepped(tmp_path, kind) as (proc, _, tmp):
        pid, _ = _harness_of(proc.pid)
        os.kill(pid, signal.SIGKILL)
        _until(lambda: proc.poll() is not None, "firmware-sim exiting after its harness died")
        assert proc.stderr is not None
        err = proc.stderr.read()
        assert proc.returncode == HARNESS_DIED, err
        assert "Traceback" not in err, err
        errors = [line for line in err.splitlines() if line.startswith("firmware-sim: error:")]
        assert len(errors) == 1 and f"avr-harness (pid {pid}) killed by SIGKILL" in errors[0], err
        assert list(tmp.iterdir()) == []


@pytest.mark.udp_multicast
@pytest.mark.parametrize("to_group", [False, True], ids=["to-firmware-sim", "to-its-process-group"])
def test_a_sigint_stops_the_stepped_firmware_cleanly(tmp_path, to_group):
    """A Ctrl-C reaches the whole foreground process group: the harness (in a session of its own) is
    stopped by firmware-sim, never taken for a harness that died."""
    with _stepped(tmp_path, "can") as (proc, _, tmp):
        harness = _harness_of(proc.pid)
        if to_group:
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGINT)
        _until(lambda: proc.poll() is not None, "firmware-sim stopping on SIGINT")
        assert proc.stderr is not None
        err = proc.stderr.read()
        assert proc.returncode == 0, err
        assert "firmware-sim: stopped;" in err and "firmware-sim: error" not in err, err
        assert " -1 reset(s)" not in err, err  # it once said so, stopped before the firmware ran
        assert _gone(*harness)
        assert list(tmp.iterdir()) == []


@pytest.mark.udp_multicast
def test_the_firmware_on_a_can_bus_answers_a_host(tmp_path):
    """``firmware-sim --avr --can``: the firmware's UART bridged onto a bus by the CAN server; the host's
    whole exchange (handshake, arm, rotor pulses following setpoints, disarm) and both ends' counts."""
    from tests.test_can_link import exchange

    with _stepped(tmp_path, "can") as (proc, url, _):
        assert url.startswith("can://udp_multicast/")
        client = exchange(url, 2)
        proc.send_signal(signal.SIGINT)
        _until(lambda: proc.poll() is not None, "firmware-sim stopping on SIGINT")
        assert proc.stderr is not None
        err = proc.stderr.read()
    assert proc.returncode == 0, err
    assert "host connected" in err, err
    assert f"{client.stats().counters.frames_out} frames in" in err, err
