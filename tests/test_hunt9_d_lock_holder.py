"""A campaign directory's lock is ``flock`` on the directory: it said that someone held it, not who. While
``hil report DIR`` drew a campaign (holding the lock for its summary.json and plots):

- ``hil montecarlo`` on DIR was refused "another session is writing this campaign directory", no session
  writing;
- a second ``hil report DIR`` said "a session is writing this campaign";
- a campaign whose session was killed (campaign.json still saying ``running``) was reported "still
  running", its last session long dead.

Now the lock's holder is recorded beside it (who, its pid) and each says who holds it. A real campaign
killed mid-run (SIGKILL of its own process group, from a subprocess's session), a real ``hil report``
subprocess drawing it; the refusals through the real store and the real CLI."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from montecarlo_support import write_quick_scenario

from hil.cli import main as hil_main
from hil.files.writing import writer_holds
from hil.montecarlo.store import MANIFEST, RUNS, ResultStore
from protocol.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


@pytest.fixture(scope="module")
def killed_campaign(tmp_path_factory) -> Path:
    """A campaign of 40 runs asked whose session was SIGKILLed after its 6th row: campaign.json says
    ``running``, no process holds the directory."""
    scenario = write_quick_scenario(tmp_path_factory.mktemp("scenario"))
    out = tmp_path_factory.mktemp("killed") / "out"
    cmd = [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", "40", "--seed", "5",
           "--workers", "1", "--batch", "1", "--out", str(out), "--no-plots"]  # fmt: skip
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 180.0
        while _rows(out) < 6:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.01)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
    assert json.loads((out / MANIFEST).read_text())["session"]["state"] == "running"
    return out


def test_while_a_report_draws_a_campaign_each_says_a_report_holds_it(killed_campaign, capsys):
    out = killed_campaign
    drawing = subprocess.Popen(
        [sys.executable, "-m", "hil", "report", str(out)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 120.0
        while not writer_holds(out):
            assert drawing.poll() is None, drawing.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.001)
        manifest = json.loads((out / MANIFEST).read_text())
        with pytest.raises(ConfigError) as refused:
            ResultStore(out, manifest)  # what `hil montecarlo` on the directory meets
        status = hil_main(["report", "--no-plots", str(out)])
        no_plots = capsys.readouterr()
        second = hil_main(["report", str(out)])
        drawn_beside = capsys.readouterr()
        still_held = drawing.poll() is None and writer_holds(out)
    finally:
        if drawing.poll() is None:
            drawing.wait(timeout=300)
        drawing.communicate()
    assert still_held, "the report let go before the others asked: inconclusive"
    said = refused.value.detail
    assert "another session is writing" not in said, said
    assert "hil report" in said and f"pid {drawing.pid}" in said, said
    assert refused.value.where == str(out)
    # the campaign's session was killed: no session runs beside a report (the lock is one)
    assert "killed" in no_plots.out and "still running" not in no_plots.out, no_plots.out
    assert status == 3, no_plots.err
    assert "a session is writing" not in drawn_beside.out, drawn_beside.out
    assert f"hil report (pid {drawing.pid}) is drawing" in drawn_beside.out, drawn_beside.out
    assert second == 3, drawn_beside.err
    assert drawing.returncode == 3, drawing.stderr[-2000:]
    assert not (out / ".holder.json").exists()  # removed as the report let go


def test_a_session_holding_the_directory_is_named_with_its_pid(killed_campaign, tmp_path):
    """The store's own refusal of a second session, through a session held in another process."""
    manifest = json.loads((killed_campaign / MANIFEST).read_text())
    code = (
        "import json, sys, time\n"
        "from hil.montecarlo.store import ResultStore\n"
        f"store = ResultStore({str(killed_campaign)!r}, json.loads(open({str(killed_campaign / MANIFEST)!r})"
        ".read()))\n"
        "print('held', flush=True)\n"
        "sys.stdin.read()\n"
        "store.close()\n"
    )
    holder = subprocess.Popen(
        [sys.executable, "-c", code], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError) as refused:
            ResultStore(killed_campaign, manifest)
    finally:
        holder.communicate("", timeout=60)
    said = refused.value.detail
    assert f"another session is writing this campaign directory (hil montecarlo, pid {holder.pid})" in said
    assert not (killed_campaign / ".holder.json").exists()
