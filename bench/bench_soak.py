"""The fault soak as a benchmark (:mod:`bench.soak`): 40 cycles of each lockstep fault (link stall, MCU
hang, brown-out, byte corruption, phone gap), each at a moment drawn over its run, 5 of each real-time one
against firmware-sim on a pty (SIGKILL and restart, phone pause, hostile datagrams, a second host) and, where
the firmware can be built, 3 of each against the firmware under simavr (killed, its harness killed, a
second host) — 229 cycles; ``--quick``: 4, 1 and 1.

Figures: cycles survived (every check of :mod:`bench.soak` passed) out of cycles run; for the board's
faults and for the phone's, detection latency (fault → its first report) p50 / p99 next to the board
client's own silence detector (``SilenceEvent`` after ``silence_after_s`` = 1 s: it catches a board that
hangs or is cut off, later); per kind, the time back in control and to steering again, p99 next to the
soak's bound (p50 in the note); the board's failsafe after the link went quiet, worst case, next to its
bound (link timeout + one pulse frame). Lockstep cycles are deterministic: their p50 and p99 differ only
where the faults fall differently against the board's and the host's periods.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from bench.common import Result
from bench.soak import AVR_KINDS, BACK_S, FAILSAFE_S, PTY_KINDS, STEER_S, Cycle, figures, soak

NAME = "soak"
SILENCE_S = 1.0  # the board client's SilenceEvent (ClientConfig.silence_after_s)


def run(quick: bool) -> list[Result]:
    load = os.getloadavg()[0]
    from firmware_sim.avr.build import missing_tools

    avr = 0 if missing_tools() else (1 if quick else 3)  # the firmware under simavr, where it can be built
    with tempfile.TemporaryDirectory(prefix="bench-soak-") as tmp:
        cycles = soak(4 if quick else 40, 1 if quick else 5, Path(tmp), avr=avr)
    figs = figures(cycles)
    total = figs["all"]
    failed = [c for c in cycles if not c.survived]
    note = f"load average {load:.2f} on {os.cpu_count()} CPUs; " + (
        "every cycle survived" if not failed else
        f"failed: {', '.join(f'{c.kind}@{c.t_fault:.1f}s ({c.problems[0]})' for c in failed[:3])}"
    )  # fmt: skip
    rows = [Result(NAME, "cycles survived", total["survived"], "cycles", "cycles run", total["cycles"], True,
                   note)]  # fmt: skip
    board = [c for c in cycles if c.kind in ("stall", "hang", "brownout", "kill", "kill_harness")]
    phone = [c for c in cycles if c.kind in ("phone_gap", "phone_pause")]
    for label, group in (("board faults", board), ("phone gaps", phone)):
        rows += _latency_rows(label, group)
    f = figs.get("stall", {}).get("failsafe_s", {})
    if f.get("max") is not None:
        rows.append(Result(NAME, "board failsafe after the link went quiet, worst (stalls)", f["max"] * 1e3,
                           "ms", "bound: link timeout + one pulse frame", FAILSAFE_S * 1e3, False,
                           f"p50 {f['p50'] * 1e3:.1f} ms over {f['n']} stalls"))  # fmt: skip
    for kind, fk in figs.items():
        if kind == "all" or fk["back_s"]["p50"] is None:
            continue
        mode = "pty" if kind in PTY_KINDS or kind in AVR_KINDS else "lockstep"
        back, steer = fk["back_s"], fk["steering_s"]
        rows.append(Result(NAME, f"{kind}: back in control p99", back["p99"], "s", "the soak's bound",
                           BACK_S[mode], False, f"p50 {back['p50']:.3f} s; {fk['survived']}/{fk['cycles']} "
                           "survived"))  # fmt: skip
        if steer["p50"] is not None:
            rows.append(Result(NAME, f"{kind}: steering again p99", steer["p99"], "s", "the soak's bound",
                               STEER_S[mode], False, f"p50 {steer['p50']:.3f} s"))  # fmt: skip
    return rows


def _latency_rows(label: str, group: list[Cycle]) -> list[Result]:
    if not group:
        return []
    g = figures(group)["all"]
    det, silence = g["detection_s"], g["silence_s"]
    if det["p50"] is None:
        return []
    fired = f"the client's silence detector fired in {silence['n']} of {len(group)} cycles"
    return [
        Result(NAME, f"detection p50 ({label})", det["p50"] * 1e3, "ms", "silence detector threshold",
               SILENCE_S * 1e3, False, fired),
        Result(NAME, f"detection p99 ({label})", det["p99"] * 1e3, "ms", "silence detector threshold",
               SILENCE_S * 1e3, False),
    ]  # fmt: skip
