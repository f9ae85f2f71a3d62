"""An input given as a named pipe (a FIFO) that no program writes to is refused naming it after a bounded
wait, where ``open()`` waited for its writer for ever: ``hil run --scenario some.fifo`` and ``hil replay
some.fifo`` hung until killed. A pipe that is written — now, later within the wait, or closed at once with
nothing in it — reads as before (``hil run --scenario <(…)`` is a use the docs give)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.files.bounded import open_input, read_document
from protocol.errors import ConfigError, InputFormatError

SCENARIOS = Path(__file__).resolve().parent.parent / "fixtures" / "scenarios"


def _fifo(tmp_path: Path, name: str = "in.fifo") -> Path:
    path = tmp_path / name
    os.mkfifo(path)
    return path


def _write_later(path: Path, data: bytes, after_s: float) -> threading.Thread:
    def write() -> None:
        time.sleep(after_s)
        with open(path, "wb") as f:  # blocks until the reader has the pipe open
            f.write(data)

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    return writer


@pytest.mark.parametrize("error", [ConfigError, InputFormatError])
def test_a_pipe_no_program_writes_to_is_refused_naming_it_within_its_wait(tmp_path, error):
    path = _fifo(tmp_path)
    start = time.monotonic()
    with pytest.raises(error, match="a pipe no program writes to") as raised:
        open_input(path, error, "scenario", writer_wait_s=0.3)
    assert str(path) in str(raised.value)
    assert time.monotonic() - start < 30.0  # bounded: it waited for ever before


@settings(max_examples=8, deadline=None)
@given(after_s=st.floats(0.0, 0.5), size=st.integers(0, 200_000))
def test_a_pipe_written_within_the_wait_reads_whole(tmp_path_factory, after_s, size):
    path = _fifo(tmp_path_factory.mktemp("pipe"))
    data = bytes(i % 251 for i in range(size))
    writer = _write_later(path, data, after_s)
    with open_input(path, ConfigError, writer_wait_s=30.0) as f:
        assert f.read() == data  # a writer that closes at once with nothing: read as empty
    writer.join(30.0)


def test_a_scenario_and_a_log_read_through_pipes_as_from_their_files(tmp_path):
    scenario = (SCENARIOS / "cubesat-1u.toml").read_bytes()
    path = _fifo(tmp_path, "scenario.fifo")
    _write_later(path, scenario, 0.2)
    assert read_document(path, ConfigError, "scenario") == scenario.decode("utf-8-sig")
    log = _fifo(tmp_path, "log.fifo")
    with pytest.raises(InputFormatError, match="a pipe no program writes to"):
        open_input(log, InputFormatError, writer_wait_s=0.2)


def test_hil_run_on_a_pipe_written_by_a_process_runs(tmp_path):
    """The path users take: ``hil run --scenario <(cat file)``, here a FIFO a shell writes."""
    path = _fifo(tmp_path, "scenario.fifo")
    writer = subprocess.Popen(["sh", "-c", f"cat {SCENARIOS / 'cubesat-1u.toml'} > {path}"])
    try:
        done = subprocess.run(
            [sys.executable, "-m", "hil", "run", "--scenario", str(path), "--duration", "1", "--no-plots",
             "--out", str(tmp_path / "runs")],
            capture_output=True, text=True, timeout=600,
        )  # fmt: skip
    finally:
        writer.kill()
        writer.wait()
    assert done.returncode == 0, done.stderr[-2000:]
