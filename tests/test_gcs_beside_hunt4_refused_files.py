"""``hil gcs RUN_DIR`` while a file of the run it serves is replaced by one it cannot read (a FIFO, whose
open would wait for a writer). The reader refuses such a file (never opened), but the refusal was raised
out of the station's pump: ``hil gcs`` printed a traceback and exited 2 — the page, and the rows it had
read, gone — for one file of the run. Now the file alone is in error: an ``events.jsonl`` refused leaves
the telemetry followed on (the status's ``error`` names the file, and clears when a regular file is back);
a ``telemetry.csv`` refused stops the reading with what was read still served. Only a directory refused on
the first read (nothing served yet) makes ``hil gcs`` exit, naming the file
(tests/test_gcs_beside_followed_run_dirs.py). Through the real CLI in a subprocess and its HTTP API."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from gcs_support import wait_for

HEADER = "t,phase,point_err_deg\n"


def rows_text(n: int, start: int = 0) -> str:
    return "".join(f"{k / 50},1,{30 - k}\n" for k in range(start, start + n))


def write_run(d: Path, rows: int) -> Path:
    d.mkdir(parents=True)
    (d / "telemetry.csv").write_text(HEADER + rows_text(rows))
    (d / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\n')
    return d


def make_fifo(path: Path) -> None:
    path.unlink()
    os.mkfifo(path)


def get(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as answer:
        return json.loads(answer.read())


@contextmanager
def serving(run: Path) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """``hil gcs RUN`` in a subprocess, and its ``/api/stats`` URL."""
    proc = subprocess.Popen([sys.executable, "-m", "hil", "gcs", str(run), "--gcs", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        if not line.startswith("ground station: http://127.0.0.1:"):  # it ended: say why
            raise AssertionError(line + (proc.stderr.read() if proc.stderr else ""))
        yield proc, line.split(": ", 1)[1].strip().replace("/?token=", "/api/stats?token=")
    finally:
        proc.terminate()
        proc.wait(10)


def run_dir_stats(api: str) -> dict:
    return get(api)["run_dir"]


@pytest.mark.parametrize("when", ["at start", "while followed"])
def test_an_events_log_refused_leaves_the_telemetry_served_and_says_which_file(tmp_path, when):
    run = write_run(tmp_path / "run", 20)
    if when == "at start":
        make_fifo(run / "events.jsonl")
    with serving(run) as (proc, api):
        wait_for(lambda: run_dir_stats(api)["rows"] == 20, 30, "the run read")
        if when == "while followed":
            make_fifo(run / "events.jsonl")
        said = wait_for(lambda: run_dir_stats(api).get("error"), 30, "the events file said refused")
        assert "events.jsonl: not a regular file" in said, said
        with open(run / "telemetry.csv", "a") as f:
            f.write(rows_text(10, start=20))
        wait_for(lambda: run_dir_stats(api)["rows"] == 30, 30, "the telemetry followed on")
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        assert run_dir_stats(api)["state"] == "following"
        # a regular file back at the path: read from its start, the error cleared
        (run / "events.jsonl").unlink()
        (run / "events.jsonl").write_text('{"t": 0.5, "kind": "note"}\n')
        wait_for(lambda: run_dir_stats(api).get("error") is None, 30, "the error cleared")
        assert run_dir_stats(api)["events"] >= 1 and proc.poll() is None


def test_a_telemetry_refused_while_followed_stops_the_reading_not_the_server(tmp_path):
    run = write_run(tmp_path / "run", 20)
    with serving(run) as (proc, api):
        wait_for(lambda: run_dir_stats(api)["rows"] == 20, 30, "the run read")
        make_fifo(run / "telemetry.csv")
        said = wait_for(lambda: run_dir_stats(api).get("error"), 30, "the telemetry said refused")
        assert "telemetry.csv: not a regular file" in said, said
        stats = run_dir_stats(api)
        assert stats["state"] == "error" and stats["rows"] == 20 and not stats["finished"]
        info = get(api.replace("/api/stats", "/api/info"))
        assert info["columns"][0] == "t", info  # the page is still served
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
