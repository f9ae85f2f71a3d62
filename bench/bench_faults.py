"""The fault campaign as a benchmark (issue 25): ``hil montecarlo SCENARIO --dispersions faults`` for
``cubesat-1u`` and ``paper-testbed`` on a 2-worker LocalCluster — every fault kind at moments drawn over
the whole run, every run's invariants checked on what it recorded.

Figures per scenario: runs, runs with an invariant violation (the target is 0) and violations by
invariant, faults injected (all kinds), detection latency (fault → its first report) and recovery time
(outage start → the host back in control) p50 / p99, runs/min. The peer of the detection latency is the
board client's own silence detector (``SilenceEvent`` after ``silence_after_s`` = 1 s), as in the soak;
the recovery time has the outage bound (``--recover-within``, 15 s) beside it.

    python -m bench faults            # 300 + 150 runs (~20 min on 2 cores)
    python -m bench faults --quick    # 24 + 12
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from bench.common import Result

NAME = "faults"
SILENCE_S = 1.0  # the board client's SilenceEvent (ClientConfig.silence_after_s)
RECOVER_WITHIN_S = 15.0
RUNS = {"cubesat-1u": (300, 24), "paper-testbed": (150, 12)}  # full, quick
SEED = 2511


def run(quick: bool) -> list[Result]:
    import logging

    import distributed  # noqa: F401 — configures its loggers on import

    from hil.montecarlo import Campaign, load_dispersions, open_client, run_campaign
    from hil.scenario import load_scenario

    logging.getLogger("distributed").setLevel(logging.WARNING)
    logging.getLogger("hil").setLevel(logging.CRITICAL)
    rows: list[Result] = []
    load = os.getloadavg()[0]
    with open_client(workers=2) as client, tempfile.TemporaryDirectory(prefix="bench-faults-") as tmp:
        for name, (full, small) in RUNS.items():
            sc = load_scenario(name)
            campaign = Campaign(sc, load_dispersions("faults", sc), small if quick else full, SEED)
            start = time.perf_counter()
            report = run_campaign(campaign, Path(tmp) / name, client, plots=False)
            wall = time.perf_counter() - start
            rows += _rows(name, report.summary, campaign.runs, wall, load)
    return rows


def _rows(name: str, s: dict, runs: int, wall: float, load: float) -> list[Result]:  # type: ignore[type-arg]
    faults = sum(s["faults_injected"].values())
    by_kind = ", ".join(f"{k} {n}" for k, n in s["faults_injected"].items())
    violations = s["invariant_violations"]
    first = "; ".join(f"run {i}: {m}" for i, m in list(s["first_violations"].items())[:3])
    out = [
        Result(
            NAME,
            f"{name}: runs with an invariant violation",
            s["runs_with_violations"],
            "runs",
            "runs",
            runs,
            False,
            f"{sum(violations.values())} violations: "
            + ", ".join(f"{k} {n}" for k, n in violations.items())
            + (f"; {first}" if first else ""),
        ),
        Result(NAME, f"{name}: faults injected", faults, "faults", note=f"{by_kind}; seed {SEED}"),
        Result(
            NAME,
            f"{name}: campaign",
            60.0 * runs / wall,
            "runs/min",
            note=f"2 workers; load average {load:.2f} on {os.cpu_count()} CPUs at the start; "
            f"exits {s['exits']}",
        ),
    ]
    det, rec = s["detection_s"].get("all"), s["recovery_s"].get("all")
    if det:
        out += [
            Result(
                NAME,
                f"{name}: detection p50",
                det["p50"] * 1e3,
                "ms",
                "silence detector threshold",
                SILENCE_S * 1e3,
                False,
                f"{det['n']} detections",
            ),
            Result(
                NAME,
                f"{name}: detection p99",
                det["p99"] * 1e3,
                "ms",
                "silence detector threshold",
                SILENCE_S * 1e3,
                False,
                f"max {det['max']:.2f} s (an unplug's reconnection included)",
            ),
        ]
    if rec:
        out += [
            Result(
                NAME,
                f"{name}: recovery p50",
                rec["p50"],
                "s",
                "outage bound",
                RECOVER_WITHIN_S,
                False,
                f"{rec['n']} outages",
            ),
            Result(
                NAME,
                f"{name}: recovery p99",
                rec["p99"],
                "s",
                "outage bound",
                RECOVER_WITHIN_S,
                False,
                f"max {rec['max']:.2f} s",
            ),
        ]
    return out
