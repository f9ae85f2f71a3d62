"""Inputs that are not regular files, where a file is read (hil.files.bounded.input_kind): a device or a
socket is refused naming it before anything opens it, and a pipe (a shell's ``<(…)``, ``… | hil replay
/dev/stdin``) is read once to its end, bounded, as the file it carries.

Before, ``hil replay /dev/zero`` read without end (``zipfile.is_zipfile`` read the "whole" device: a
MemoryError after gigabytes), a terminal or serial port given as a scenario waited for input for ever,
a pipe was not recognised as any log, and a folder of logs holding a FIFO hung on it.
"""

from __future__ import annotations

import gzip
import io
import os
import resource
import shutil
import socket
import subprocess
import sys
import tarfile
import threading
import time
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import assert_same_samples
from test_log_json_and_variants import json_records, real_export, write_json

from hil.files.bounded import FILE, FOLDER, PIPE, input_kind, read_document
from hil.logs import logs_inside, read_log
from hil.scenario import load_scenario
from protocol.errors import ConfigError, InputFormatError

ROOT = Path(__file__).resolve().parents[1]
FIXTURE_CSV = ROOT / "fixtures" / "logs" / "simulated_testbed_4s.csv"
BROAD = ROOT.parent / "shared" / "data" / "broad" / "01_undisturbed_slow_rotation_A.mat"
DEVICES = ("/dev/zero", "/dev/urandom", "/dev/null")
WAIT_S = 60.0  # a read that has not ended by then hangs


@contextmanager
def fed_pipe(path: Path, data: bytes, pieces: list[int] | None = None) -> Iterator[Path]:
    """A FIFO at ``path`` that a thread writes ``data`` into (in ``pieces`` of those sizes, cycled: a
    burst, then a trickle), then closes; a reader that stops early breaks the pipe, which ends the
    writer. The thread is joined on leaving."""
    os.mkfifo(path)

    def write() -> None:
        sizes = pieces or [len(data) or 1]
        try:
            with open(path, "wb") as f:
                at, i = 0, 0
                while at < len(data):
                    f.write(data[at : at + sizes[i % len(sizes)]])
                    f.flush()
                    at += sizes[i % len(sizes)]
                    i += 1
        except BrokenPipeError:
            pass  # the reader stopped reading (a bound reached): the writer's end

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    try:
        yield path
    finally:
        _drain_until_done(path, writer)


def _drain_until_done(path: Path, writer: threading.Thread) -> None:
    """Read the FIFO until ``writer`` has ended (its open returns once a reader is there, its writes once
    they are read). Opened without blocking: a writer that had closed its end but not yet returned when
    this looked left a blocking open waiting for a writer that would never come (a hang under load)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        end = time.monotonic() + WAIT_S
        while writer.is_alive() and time.monotonic() < end:
            try:
                if not os.read(fd, 1 << 16):
                    time.sleep(0.005)  # no writer now: it is returning, or not yet at its open
            except BlockingIOError:
                time.sleep(0.005)  # a writer, nothing written yet
    finally:
        os.close(fd)
    assert not writer.is_alive()


def zipped(folder: Path) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(folder.iterdir()):
            z.write(p, f"Recording/{p.name}")
    return out.getvalue()


def tarred(folder: Path) -> bytes:
    out = io.BytesIO()
    with tarfile.open(fileobj=out, mode="w:gz") as t:
        t.add(folder, "Recording")
    return out.getvalue()


@pytest.fixture(scope="module")
def export(tmp_path_factory) -> Path:
    return real_export(tmp_path_factory.mktemp("export") / "Recording")


# --------------------------------------------------------------------------- devices and sockets
@pytest.mark.parametrize("device", DEVICES)
def test_a_device_given_as_a_log_is_refused_naming_it_before_it_is_read(device):
    with pytest.raises(InputFormatError, match="a character device, not a file") as err:
        read_log(device)
    assert err.value.path == device


def test_a_socket_given_as_a_log_is_refused(tmp_path):
    path = tmp_path / "sock"
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(path))
        with pytest.raises(InputFormatError, match="a socket, not a file"):
            read_log(path)
        assert input_kind(tmp_path) == FOLDER and input_kind(FIXTURE_CSV) == FILE


def test_hil_replay_of_dev_zero_says_so_at_once_without_a_traceback(tmp_path):
    """The real command: a typed error naming the device, exit status 2, in well under the time a read of
    gigabytes took (and with memory that could not hold them)."""
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "replay", "/dev/zero", "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30)),
    )
    assert proc.returncode == 2, proc.stderr  # hil's status for an error of the project's tree
    assert "/dev/zero: a character device, not a file" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_terminal_given_as_a_scenario_is_refused_not_waited_on():
    """A serial port or a terminal given where a file goes (``--scenario /dev/ttyUSB0`` for ``--port``):
    its read would wait for input for ever. Here a real pseudo-terminal's slave, nobody writing to it."""
    master, slave = os.openpty()
    try:
        tty = os.ttyname(slave)
        with pytest.raises(ConfigError, match="a character device, not a file") as err:
            load_scenario(Path(tty))
        assert err.value.where == tty
        with pytest.raises(InputFormatError, match="character device"):
            read_document(tty, InputFormatError)
    finally:
        os.close(slave)
        os.close(master)


# --------------------------------------------------------------------------- pipes
@pytest.mark.parametrize("wrapping", ["zip", "tar.gz", "folder's files as JSON", "csv", "csv.gz", "mat"])
def test_a_log_through_a_pipe_reads_as_the_file_it_carries(tmp_path, export, wrapping):
    """Each wrapping a log comes in, piped: the same samples, bit for bit, as the file read from disk."""
    if wrapping == "zip":
        data, reference = zipped(export), read_log(export)
    elif wrapping == "tar.gz":
        data, reference = tarred(export), read_log(export)
    elif wrapping == "folder's files as JSON":
        path = write_json(tmp_path / "Recording.json", json_records())
        data, reference = path.read_bytes(), read_log(path)
    elif wrapping == "csv":
        data, reference = FIXTURE_CSV.read_bytes(), read_log(FIXTURE_CSV)
    elif wrapping == "csv.gz":
        data, reference = gzip.compress(FIXTURE_CSV.read_bytes()), read_log(FIXTURE_CSV)
    else:
        if not BROAD.is_file():
            pytest.skip("the shared BROAD trial is not here")
        data, reference = BROAD.read_bytes(), read_log(BROAD)
    with fed_pipe(tmp_path / "pipe", data) as pipe:
        assert input_kind(pipe) == PIPE
        log = read_log(pipe)
    assert log.format == reference.format
    assert_same_samples(log, reference)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pieces=st.lists(st.integers(1, 70_000), min_size=1, max_size=6))
def test_a_pipe_written_in_bursts_and_trickles_reads_whole(tmp_path_factory, export, pieces):
    """However the writer hands the bytes over (one byte at a time between bursts of tens of kB), the
    pipe is read to its end: never a part of it taken for the whole."""
    folder = tmp_path_factory.mktemp("pipe")
    with fed_pipe(folder / "pipe", zipped(export), pieces) as pipe:
        assert_same_samples(read_log(pipe), read_log(export))


def test_a_pipe_longer_than_any_log_is_refused_naming_it(tmp_path, monkeypatch):
    """Bounded as a file of a log is (MAX_MEMBER_BYTES, made small here): an error naming the pipe once
    the bound is passed, the writer's end broken — not a spool that grows with whatever is written."""
    import hil.logs.archive as archive

    monkeypatch.setattr(archive, "MAX_MEMBER_BYTES", 1 << 20)
    with fed_pipe(tmp_path / "pipe", b"0" * (4 << 20), [1 << 16]) as pipe:
        with pytest.raises(InputFormatError, match="larger than any log") as err:
            read_log(pipe)
    assert err.value.path == str(tmp_path / "pipe")


def test_hil_replay_reads_a_log_piped_to_its_stdin(tmp_path, export):
    """The real command, fed as a user pipes a download into it: ``… | hil replay /dev/stdin``."""
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "replay", "/dev/stdin", "--no-plots", "--out", str(tmp_path / "o")],
        input=zipped(export),
        capture_output=True,
        timeout=WAIT_S * 2,
    )
    assert proc.returncode == 0, proc.stderr.decode()
    assert b"sensorlogger" in proc.stdout and (tmp_path / "o" / "estimates.csv").is_file()


# --------------------------------------------------------------------------- in a folder
def test_a_folder_holding_a_fifo_and_a_device_link_reads_as_the_log_without_them(tmp_path, export):
    folder = tmp_path / "Recording"
    shutil.copytree(export, folder)
    os.mkfifo(folder / "Accelerometer.csv")  # nobody writes it: opening it would wait for ever
    (folder / "Gravity.csv").symlink_to("/dev/zero")
    assert_same_samples(read_log(folder), read_log(export))


def test_a_folder_of_logs_holding_a_fifo_is_probed_past_it(tmp_path, export):
    """A folder of trials (:func:`hil.logs.logs_inside`, the hint given when a folder is no log itself):
    a FIFO among them (nobody writing it) and a link to a device are passed over, not opened."""
    trials = tmp_path / "trials"
    shutil.copytree(export, trials / "a")
    os.mkfifo(trials / "b.csv")
    (trials / "c.csv").symlink_to("/dev/urandom")
    shutil.copytree(export, trials / "d")
    assert logs_inside(trials) == [trials / "a", trials / "d"]
