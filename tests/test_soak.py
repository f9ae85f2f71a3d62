"""The short fault soak CI runs (``python -m bench.soak --ci``, :mod:`bench.soak`): two cycles of each
fault — link stall, MCU hang, brown-out, 1 % byte corruption and a phone gap in lockstep; firmware-sim
killed and restarted, the phone paused and hostile datagrams in real time over a pty — every check of every
cycle passed (no crash or hang, each fault detected and reported with its cause within its bound, the
board's failsafe within link timeout + one frame, re-arming only through the handshake, no stale row, the
host back in control and steering again, nothing logged lost)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
KINDS = {"stall", "hang", "brownout", "corruption", "phone_gap", "kill", "phone_pause", "hostile"}


def test_the_short_fault_soak(tmp_path):
    out = tmp_path / "soak.json"
    done = subprocess.run(
        [sys.executable, "-m", "bench.soak", "--ci", "--json", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    report = json.loads(out.read_text())
    failed = [c for c in report["cycles"] if not c["survived"]]
    assert not failed, "\n".join(f"{c['kind']} at {c['t_fault']:.2f} s: {c['problems']}" for c in failed)
    assert done.returncode == 0, done.stderr[-3000:]
    cycles = report["cycles"]
    assert {c["kind"] for c in cycles} == KINDS and len(cycles) == 2 * len(KINDS)
    causes = {c["kind"]: c["cause"] for c in cycles}
    assert causes["hang"] == "reset WATCHDOG" and causes["brownout"] == "reset BROWN_OUT"
    assert causes["kill"] == "reset POWER_ON" and causes["stall"] == "failsafe"
    for c in cycles:
        if c["kind"] == "stall":
            assert 0.25 <= c["failsafe_s"] <= 0.27  # the board's own record: timeout + one 50 Hz frame
        if c["kind"] not in ("corruption", "hostile"):
            assert c["detection_s"] is not None and c["back_s"] is not None and c["steering_s"] is not None
    figures = report["figures"]["all"]
    assert figures["survived"] == figures["cycles"] == len(cycles)
