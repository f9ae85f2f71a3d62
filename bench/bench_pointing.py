"""Pointing through the full protocol: the shipped scenarios' slews (cubesat-1u: 90°; paper-testbed: 60°)
in lockstep through :func:`hil.runtime.run` — the host's estimator (the scenario's, the paper's) on the
simulated phone, controller, steering and setpoints, the emulated board's frames, watchdog and pulse
widths through its calibration maps, the world's drives and plant — over a few seeds (the scenario's
``seed``: phone noise, biases and jitter).

Per run: the settle time to 0.5° (from the slew's start; inf: above 0.5° at the end, never settled), the
final pointing error (the run's last tick) and the peak pointing error over the run's last 10 s (the
hold's limit cycle, if any). Lower is better for all three. The note gives the estimator's mean error
over the same 10 s: the controller holds the *estimate*, so a hold cannot point better than that.

The peer is the same figure from the **baseline** revision (``BASELINE_REV``, main before the board's
pulses went to 0.5 µs ticks with sigma-delta dithering and the hold law was made to match; override with
the environment variable ``BENCH_POINTING_BASELINE=<git rev>``, empty for none): this file run as a script
from a ``git archive`` of that revision in a temporary directory, in a subprocess, in the same run —
before and after, measured side by side on the same machine and load. Without git or the revision, the
figures come without a peer (the note says why).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path
from typing import Any

NAME = "pointing"
SCENARIOS = ("cubesat-1u", "paper-testbed")
SEEDS = (1, 2, 3)
SETTLE_DEG = 0.5
HOLD_WINDOW_S = 10.0
BASELINE_REV = "2659115"
"""main as it was before this work (1 µs pulse widths, the hold limit-cycling at 0.2–0.8°)."""
ROOT = Path(__file__).resolve().parent.parent


def measure(scenario: str, seed: int) -> dict[str, Any]:
    """One run of ``scenario`` with ``seed``, no run directory: its figures. Uses only what the baseline
    has too (``load_scenario``, ``run``, ``RunOptions``, the trace), so it runs on either tree."""
    import numpy as np

    from hil.runtime import RunOptions, run
    from hil.scenario import load_scenario

    sc = load_scenario(scenario)
    result = run(sc.with_changes(seed=seed), RunOptions(out_root=None))
    tr = result.trace.arrays()
    t, err = tr["t"], tr["point_err_deg"]
    outside = np.nonzero(~(err <= SETTLE_DEG))[0]
    if len(outside) == 0:
        settle = float(t[0])
    elif outside[-1] == len(t) - 1:
        settle = math.inf
    else:
        settle = float(t[outside[-1] + 1])
    window = t >= t[-1] - HOLD_WINDOW_S
    hold = err[window]
    return {
        "scenario": scenario,
        "seed": seed,
        "exit": result.summary["exit"],
        "settle_s": settle,
        "final_error_deg": float(err[-1]),
        "hold_peak_deg": float(np.max(hold)),
        "estimate_hold_deg": float(np.mean(tr["est_err_deg"][window])),
    }


def _cases(quick: bool) -> list[tuple[str, int]]:
    if quick:
        from hil.scenario import load_scenario

        return [(name, load_scenario(name).seed) for name in SCENARIOS]
    return [(name, seed) for name in SCENARIOS for seed in SEEDS]


def _baseline(cases: list[tuple[str, int]]) -> tuple[dict[tuple[str, int], dict[str, Any]], str]:
    """The baseline revision's figures for ``cases`` (empty, and why, when there is none)."""
    rev = os.environ.get("BENCH_POINTING_BASELINE", BASELINE_REV)
    if not rev:
        return {}, "no baseline (BENCH_POINTING_BASELINE is empty)"
    try:
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", rev], capture_output=True, check=True, timeout=60
        ).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        return {}, f"no baseline: git archive {rev} failed ({exc})"
    with tempfile.TemporaryDirectory(prefix="bench-pointing-") as tmp:
        with tarfile.open(fileobj=BytesIO(archive)) as tar:
            tar.extractall(tmp, filter="data")
        env = dict(os.environ, PYTHONPATH=tmp)
        args = [sys.executable, str(Path(__file__).resolve()), "--measure", json.dumps(cases)]
        proc = subprocess.run(args, capture_output=True, text=True, env=env, cwd=tmp, timeout=3600)
        if proc.returncode != 0:
            return {}, f"no baseline: its runs failed ({proc.stderr.strip().splitlines()[-1:]})"
        rows = json.loads(proc.stdout.strip().splitlines()[-1])
    return {(r["scenario"], r["seed"]): r for r in rows}, f"peer: revision {rev} (main before this work)"


def run(quick: bool) -> list[Any]:
    from bench.common import Result

    cases = _cases(quick)
    ours = [measure(name, seed) for name, seed in cases]
    base, why = _baseline(cases)
    results = []
    peer = f"baseline {os.environ.get('BENCH_POINTING_BASELINE', BASELINE_REV)}" if base else ""
    for row in ours:
        other = base.get((row["scenario"], row["seed"]))
        label = f"{row['scenario']} seed {row['seed']}"
        note = f"{why}; the estimate's mean error over the last {HOLD_WINDOW_S:g} s " + (
            f"{row['estimate_hold_deg']:.3f} deg"
            + (f" (baseline {other['estimate_hold_deg']:.3f})" if other else "")
        )
        for i, (key, figure, unit) in enumerate(
            (
                ("settle_s", "settle time to 0.5 deg", "s"),
                ("final_error_deg", "final pointing error", "deg"),
                ("hold_peak_deg", f"peak pointing error, last {HOLD_WINDOW_S:g} s", "deg"),
            )
        ):
            results.append(
                Result(
                    NAME,
                    f"{label}: {figure}",
                    row[key],
                    unit,
                    peer,
                    None if other is None else other[key],
                    False,
                    note if i == 0 else "",
                )
            )
    return results


if __name__ == "__main__" and sys.argv[1:2] == ["--measure"]:
    rows = [measure(name, seed) for name, seed in json.loads(sys.argv[2])]
    print(json.dumps(rows))
