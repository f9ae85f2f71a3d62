"""Runs compared (``hil gcs RUN_A RUN_B``) when one of them cannot be read: a file of an overlay that became
a FIFO (or anything else :class:`~hil.gcs.rundir.RunDirSource` refuses) raised out of the comparison's poll,
which stopped the whole station's pump — and ``hil gcs`` exited with a traceback-like error — for a run that
is only drawn over the first one. Now that run alone is marked ``error`` (with why, in its status and
``/api/stats``), and the first run goes on being followed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.request
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


def stats(api: str) -> dict:
    with urllib.request.urlopen(api, timeout=10) as answer:
        return json.loads(answer.read())


@pytest.mark.parametrize("name", ["events.jsonl", "telemetry.csv"])
@pytest.mark.parametrize("when", ["at start", "while followed"])
def test_an_overlay_that_cannot_be_read_is_marked_in_error_and_the_first_run_goes_on(tmp_path, name, when):
    a = write_run(tmp_path / "a", 20)
    b = write_run(tmp_path / "b", 20)

    def fifo() -> None:
        (b / name).unlink()
        os.mkfifo(b / name)

    if when == "at start":
        fifo()
    proc = subprocess.Popen([sys.executable, "-m", "hil", "gcs", str(a), str(b), "--gcs", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert line.startswith("ground station: http://127.0.0.1:"), line + proc.stderr.read()
        api = line.split(": ", 1)[1].strip().replace("/?token=", "/api/stats?token=")
        wait_for(lambda: stats(api)["compare"]["a"]["rows"] == 20, 30, "the first run read")
        if when == "while followed":
            fifo()
        overlay = wait_for(
            lambda: stats(api)["compare"]["b"]["state"] == "error" and stats(api)["compare"]["b"],
            30,
            "the overlay in error",
        )
        assert f"{name}: not a regular file" in overlay["error"]
        with open(a / "telemetry.csv", "a") as f:
            f.write(rows_text(10, start=20))
        wait_for(lambda: stats(api)["compare"]["a"]["rows"] == 30, 30, "the first run followed on")
        assert proc.poll() is None, proc.stderr.read()
        assert stats(api)["compare"]["a"]["state"] == "following"
    finally:
        proc.terminate()
        proc.wait(10)
