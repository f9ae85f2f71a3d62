"""The closed loop over the firmware's USB link (issue 30): ``hil run --port`` plays the phone's accessory
app, the real firmware under simavr (stepped by ``firmware-sim --avr --usb --world``) enumerates the
emulated phone on its USB host port, switches it into accessory mode and carries the protocol over its
bulk pipes, and the world's spacecraft moves under its pulses. Real processes and ptys throughout; each run
is a few seconds after the slew starts (the default scenario to its end, by hand: docs/firmware_sim.md)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from firmware_sim.avr.build import ensure_built

pytestmark = pytest.mark.firmware

RUN_TIMEOUT_S = 60.0
"""Wall seconds a run may take here (each takes ~8-15 s on the shared 2-core machine)."""


def _hil_run(
    port: str, phone_port: int, out: Path, duration_s: float
) -> tuple[subprocess.CompletedProcess[str], dict[str, Any], list[dict[str, Any]]]:
    """``hil run --port PORT`` for ``duration_s`` after the slew starts: the process, its summary.json and
    its events.jsonl."""
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--port", port, "--phone", f"127.0.0.1:{phone_port}",
         "--duration", str(duration_s), "--no-plots", "--out", str(out)],
        capture_output=True, text=True, timeout=RUN_TIMEOUT_S,
    )  # fmt: skip
    runs = list(out.glob("*/summary.json"))
    assert runs, done.stderr
    summary = json.loads(runs[0].read_text())
    events = [json.loads(line) for line in (runs[0].parent / "events.jsonl").read_text().splitlines()]
    return done, summary, events


def _board_logs(events: list[dict[str, Any]]) -> list[str]:
    return [e["text"] for e in events if e["kind"] == "board_log"]


def test_hil_run_through_the_usb_path_completes(tmp_path: Path, phone_port: int) -> None:
    ensure_built()
    url = f"spawn://firmware-sim?board=firmware&usb=1&world=cubesat-1u&phone=udp://127.0.0.1:{phone_port}"
    done, summary, events = _hil_run(url, phone_port, tmp_path, 1.0)
    assert done.returncode == 0, done.stderr
    assert summary["exit"] == "completed" and summary["mode"] == "port"
    assert summary["slew_started"] and summary["tasks"]["control"]["runs"] > 20
    # the HelloReply came back over USB: the firmware's identity (the Python board says "emulator")
    assert "ADK-VSCMG" in summary["board"] and "serial SIM0001" in summary["board"], summary["board"]
    logs = _board_logs(events)
    assert "USB accessory connected, product 0x2d01" in logs, logs  # the firmware's own word, over USB
    assert summary["failsafe_events"] == 0 and summary["board_resets"] == 0


def test_phone_detached_mid_run_fails_safe_and_the_run_goes_on(tmp_path: Path, phone_port: int) -> None:
    """The phone pulled off the board's USB host port for 1 s mid-run (``--usb-detach``): the board hears
    nothing and fails safe within its link timeout, the host reports the outage; plugged back, the
    firmware enumerates the phone and switches it into accessory mode again, the host re-arms and the run
    completes. firmware-sim's stop line says the phone ended in accessory mode."""
    ensure_built()
    link = tmp_path / "board"
    sim = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--avr", "--usb", "--world", "cubesat-1u", "--phone",
         f"udp://127.0.0.1:{phone_port}", "--link", str(link), "--usb-detach", "7:1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert sim.stdout is not None
        path = sim.stdout.readline().strip()
        assert path.startswith("/dev/"), sim.stderr.read() if sim.poll() is not None else path
        done, summary, events = _hil_run(str(link), phone_port, tmp_path / "runs", 10.0)
        sim.send_signal(signal.SIGTERM)
        _, err = sim.communicate(timeout=30)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.communicate()
    assert done.returncode == 0, done.stderr
    assert sim.returncode == 0, err
    assert summary["exit"] == "completed" and summary["slew_started"]
    logs = _board_logs(events)
    assert "USB accessory disconnected" in logs, logs
    assert "link lost: nothing valid for 250 ms" in logs, logs  # the link watchdog, at its timeout
    assert summary["failsafe_events"] >= 1 and summary["rearms"] >= 1 and summary["board_resets"] == 0
    outages = summary["outages"]
    assert outages and all(o["recovered"] for o in outages), outages
    # The detach's outage: stale then failsafe (two 20 ms apart before the firmware dropped the telemetry it
    # had queued for the phone that left: docs/firmware_sim.md, "Over USB"). On a loaded machine short
    # stale outages may come before or after it (a host late by the 250 ms link timeout, telemetry late by
    # the stale limit): they are recovered, and not the detach's.
    at = next(i for i, o in enumerate(outages) if "failsafe" in o["causes"])
    start, end = at, at + 1
    while start > 0 and outages[start]["start"] - outages[start - 1]["end"] < 0.1:
        start -= 1
    while end < len(outages) and outages[end]["start"] - outages[end - 1]["end"] < 0.1:
        end += 1
    assert outages[end - 1]["end"] - outages[start]["start"] < 3.0, outages
    # From the board's failsafe on: the host re-arms, the board says armed, then the host is back in control.
    failsafe = next(i for i, e in enumerate(events) if e["kind"] == "board_state" and e["new"] == "FAILSAFE")
    kinds = [e["kind"] for e in events[failsafe:]]
    assert kinds.index("rearm_sent") < kinds.index("rearmed") < kinds.index("board_back"), kinds
    run_dir = next((tmp_path / "runs").iterdir())
    last_row = (run_dir / "telemetry.csv").read_text().splitlines()[-1]
    assert float(last_row.split(",")[0]) > outages[-1]["end"] + 1.0  # the run went on after the outage
    stop = err.strip().splitlines()[-1]
    assert "phone on USB: accessory (vscmg-hil / ADK-VSCMG)" in stop, err


def _lockstep_usb_run(**options: str) -> dict[str, Any]:
    """cubesat-1u through the firmware on its USB link in lockstep (``emu://?board=firmware&usb=1``), 4 s
    after the slew starts: the run's summary."""
    from dataclasses import replace

    from hil.runtime.loop import RunOptions, run
    from hil.scenario import load_scenario

    scenario = load_scenario("cubesat-1u")
    board = {**scenario.board_options, "board": "firmware", "usb": "1", **options}
    return run(replace(scenario, board_options=board), RunOptions(out_root=None, duration_s=4.0)).summary


def test_a_lockstep_phone_detach_over_usb_replays_exactly() -> None:
    """The same fault in lockstep (the in-process firmware board, ``usb_detach`` in its URL): the phone off
    from t = 5 s for 1 s fails the board safe and the host re-arms it, and the run replays exactly."""
    ensure_built()
    first = _lockstep_usb_run(usb_detach="5:1")
    assert first["exit"] == "completed" and first["slew_started"]
    assert first["failsafe_events"] == 1 and first["rearms"] == 1 and first["board_resets"] == 0
    (outage,) = first["outages"]
    assert outage["recovered"] and outage["causes"] == ["stale", "failsafe"], outage
    assert 5.0 < outage["start"] < 5.3 and outage["duration_s"] < 2.0, outage  # stale 250 ms after
    assert _lockstep_usb_run(usb_detach="5:1")["outages"] == first["outages"]
