"""The short fault soak CI runs (``python -m bench.soak --ci``, :mod:`bench.soak`): two cycles of each
fault, each at a moment drawn over a run's whole span — link stall, MCU hang, brown-out, byte corruption
and a phone gap in lockstep (each cycle a run of its own, checked with the fault campaigns' invariants);
firmware-sim killed and restarted, the phone paused, hostile datagrams and a second host on the board's
port in real time over a pty; on a CAN bus (classic and FD) the board killed, frozen, a noisy node, the
phone paused — and the firmware under simavr killed, its harness killed, a second host refused. Every
check of every cycle passed: no crash or hang, each fault detected and reported with its cause within its
bound, the board's failsafe within link timeout + one frame, re-arming only through the
handshake, no stale row, the host back in control and steering again, nothing logged lost."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LOCKSTEP = {"stall", "hang", "brownout", "corruption", "phone_gap"}
PTY = {"kill", "phone_pause", "hostile", "second_host"}
AVR = {"kill", "kill_harness", "second_host"}
CAN = {"kill", "freeze", "noise", "phone_pause"}


def _soak(tmp_path: Path, *args: str) -> dict:  # type: ignore[type-arg]
    out = tmp_path / "soak.json"
    done = subprocess.run(
        [sys.executable, "-m", "bench.soak", "--json", str(out), *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert out.exists(), f"the soak wrote no report (exit {done.returncode}):\n{done.stderr[-3000:]}"
    report = json.loads(out.read_text())
    failed = [c for c in report["cycles"] if not c["survived"]]
    assert not failed, "\n".join(f"{c['kind']} at {c['t_fault']:.2f} s: {c['problems']}" for c in failed)
    assert done.returncode == 0, done.stderr[-3000:]
    figures = report["figures"]["all"]
    assert figures["survived"] == figures["cycles"] == len(report["cycles"])
    return report


def test_the_short_fault_soak(tmp_path):
    report = _soak(tmp_path, "--ci", "--seed", "25")
    cycles = report["cycles"]
    assert {c["kind"] for c in cycles} == LOCKSTEP | PTY and len(cycles) == 2 * len(LOCKSTEP | PTY)
    lockstep = [c for c in cycles if c["mode"] == "lockstep"]
    assert len({round(c["t_fault"], 3) for c in lockstep}) == len(lockstep)  # drawn, not fixed moments
    for c in cycles:
        seen = not c["cause"].startswith(("unseen", "none"))
        if c["kind"] == "hang" and seen:
            assert "reset" in c["cause"] and "stale" in c["cause"]
        if c["kind"] == "brownout" and seen:
            assert "reset" in c["cause"]
        if c["kind"] == "stall" and c["failsafe_s"] is not None:
            assert 0.25 <= c["failsafe_s"] <= 0.27  # the board's own record: timeout + one 50 Hz frame
        if c["kind"] == "kill":
            assert c["cause"] == "reset POWER_ON" and c["back_s"] is not None and c["steering_s"] is not None
        if c["kind"] == "second_host":
            assert c["cause"] == "refused: holder named"


@pytest.mark.udp_multicast
def test_the_short_soak_on_a_can_bus(tmp_path):
    """The Python board with its world on a ``udp_multicast`` bus, classic CAN and CAN FD, in real time:
    killed and restarted, frozen (a stalled board), a noisy node's damaged segments, the phone paused —
    each at a drawn moment, every check passed (issue 31)."""
    report = _soak(tmp_path, "--cycles", "0", "--pty", "0", "--can", "1", "--seed", "31")
    cycles = report["cycles"]
    assert sorted(c["mode"] for c in cycles) == ["can"] * len(CAN) + ["can-fd"] * len(CAN)
    for mode in ("can", "can-fd"):
        assert {c["kind"] for c in cycles if c["mode"] == mode} == CAN
    for c in cycles:
        if c["kind"] == "kill":
            assert c["cause"] == "reset POWER_ON" and c["back_s"] is not None and c["steering_s"] is not None
        if c["kind"] == "freeze":
            assert c["cause"] == "failsafe" and c["detection_s"] is not None
        if c["kind"] == "noise":
            assert c["cause"].split()[0].isdigit() and int(c["cause"].split()[0]) > 0


@pytest.mark.firmware
def test_the_short_soak_against_the_firmware_under_simavr(tmp_path):
    """The firmware's board killed (its harness with it) and restarted, its harness killed under
    firmware-sim, a second host refused — each at a drawn moment, the host recovering every time."""
    report = _soak(tmp_path, "--cycles", "0", "--pty", "0", "--avr", "2", "--kinds", *sorted(AVR))
    cycles = report["cycles"]
    assert {c["kind"] for c in cycles} == AVR and all(c["mode"] == "avr" for c in cycles)
    for c in cycles:
        if c["kind"] in ("kill", "kill_harness"):
            assert c["cause"] == "reset POWER_ON" and c["back_s"] is not None
