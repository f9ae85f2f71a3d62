"""A board that restarts before it answers the host's first handshake — its main loop hung at its boot, the
MCU watchdog resetting it ~0.5 s later, the host's Hello answered by the new boot — is a run with no board
from its first try on. It was reported as a reset at the answer with an outage of 0.02 s (from the answer
to the re-arm): the host's 0.6 s without any board went into no record, and ``--recover-within`` did not
apply to it. Now the reset says it came before the first session (``no_board_since`` in its
``events.jsonl`` record and in the event) and its outage runs from the host's first try.

Both the in-process board (lockstep, drawn hang moments) and ``firmware-sim`` behind a real pty driven by
``hil run --port`` in a process of its own."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from fault_support import check_honest_end, faulted_run_settings, run_faults
from hypothesis import given
from hypothesis import strategies as st
from sim_support import Sim, sims
from test_pty_fault_campaign import HOST_WALL_S, ROOT, _free_udp_port

from hil.runtime.invariants import InjectedFault

MCU_WATCHDOG_S = 0.5  # the emulated board's MCU watchdog: a hung board is silent this long at least


@faulted_run_settings(max_examples=6)
@given(hang_at=st.floats(0.0, 0.04))
def test_a_board_hung_at_its_boot_is_no_board_from_the_start_with_its_true_outage(hang_at: float):
    faults = [InjectedFault("hang", hang_at)]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)
    connecting = next(e["t"] for e in recorder.events if e["kind"] == "connecting")
    resets = [e for e in recorder.events if e["kind"] == "board_reset"]
    assert len(resets) == 1, resets
    assert resets[0]["no_board_since"] == connecting, resets[0]
    assert "before it answered the host's first handshake" in resets[0]["evidence"], resets[0]
    outages = recorder.summary["outages"]
    assert outages and outages[0]["start"] == connecting, outages
    assert outages[0]["duration_s"] >= MCU_WATCHDOG_S, outages


def test_hil_run_with_its_board_hung_at_boot_on_a_pty_says_so(tmp_path: Path):
    """``hil run --port`` started first, then ``firmware-sim --hang-at 0`` on that pty (the board hangs
    and its watchdog resets it as it starts, about when its port appears): the run completes, and its one
    reset — the board's own word at the first handshake — is one before the first session, its outage
    from the host's first try on the open port (it was from the answer on: the host's own wait in no
    record)."""
    link = tmp_path / "board"
    phone = _free_udp_port()
    out_dir = tmp_path / "runs"
    with sims(tmp_path) as boards:
        host = subprocess.Popen(
            [sys.executable, "-m", "hil", "run", "--port", str(link), "--phone", f"udp://127.0.0.1:{phone}",
             "--duration", "1.0", "--recover-within", "6.0", "--no-plots", "--out", str(out_dir)],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT,
        )  # fmt: skip
        try:
            while not out_dir.exists() or not any(out_dir.iterdir()):  # the host is trying the port
                assert host.poll() is None, host.communicate()[0][-2000:]
                time.sleep(0.01)
            boards.append(Sim(tmp_path, link, "--world", "cubesat-1u", "--phone", f"udp://127.0.0.1:{phone}",
                              "--hang-at", "0"))  # fmt: skip
            out, _ = host.communicate(timeout=HOST_WALL_S)
        finally:
            if host.poll() is None:
                host.kill()
                host.wait()
    (run_dir,) = [p for p in out_dir.iterdir() if p.is_dir()]
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["exit"] == "completed", (summary["exit"], out[-2000:])
    events = [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines()]
    (reset,) = [e for e in events if e["kind"] == "board_reset"]
    assert reset["cause"] == "WATCHDOG" and "no_board_since" in reset, reset
    first = summary["outages"][0]
    assert first["start"] == reset["no_board_since"] <= reset["t"], (reset, summary["outages"])
    assert first["end"] is not None and first["end"] > reset["t"], summary["outages"]
