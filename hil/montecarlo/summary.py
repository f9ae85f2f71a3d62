"""A campaign's summary: percentiles of every metric over the runs that finished, and pass rates against
the scenario's requirements.

Requirements (each a pass/fail per run; a failed run passes none):

- ``settle``: the run settled within its duration (``settle_s`` ≤ the run's duration);
- ``final_error``: ``final_error_deg`` ≤ the scenario's ``settle_deg``;
- ``gimbal_rate``: ``peak_gimbal_rate`` ≤ the array's gimbal-rate limit;
- ``all``: all three.

Pass rates are over every finished run, failed ones included (as not passing), with a 95 % Wilson score
interval: with 100 runs an observed 99 % means somewhere between ~94.5 and ~99.8 %. A campaign whose
duration is shorter than its slew needs to settle (:meth:`hil.scenario.Scenario.time_to_judge`) says so
(``too_short_to_judge``, printed under the requirements): its misses are the duration's.

What a figure could not use is said, never passed over: an ok run whose metric is empty or NaN, or below
zero where no run can be (:data:`NON_NEGATIVE`: a row hil did not write), is left out of that metric's
figures and counted (``left_out``; ``n`` the runs in them), and is not judged by a requirement on that
metric (``not_judged``: counted as not passing; a negative settle time or final error once passed); the
lines of runs.csv that were dropped (``dropped_lines``: damaged, a bad run index, an earlier row of a run
written again) and a not-ok run with no error recorded (its status not ``ok``, its error empty) are
printed by :func:`format_table`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hil.runtime.invariants import INVARIANTS

from .metrics import METRICS
from .store import Results

PERCENTILES = (50, 95, 99)
NON_NEGATIVE = frozenset(METRICS) - {"min_delta"}
"""The metrics no run can have below zero (times, error angles, a peak |rate|, a count). ``min_delta``, a
determinant, can come out a rounding below zero at a singularity: any number of it is read."""
NO_ERROR = "no error recorded (its status is not ok)"
"""What the table says of a not-ok run whose row holds no error: a status other than ``ok`` or ``failed``
(read_runs takes every status but ``ok`` as a failure), or an emptied error cell."""


def requirements(
    duration_s: float, settle_deg: float, max_gimbal_rate: float
) -> dict[str, tuple[str, float]]:
    """Requirement name → (metric, upper limit)."""
    return {
        "settle": ("settle_s", duration_s),
        "final_error": ("final_error_deg", settle_deg),
        "gimbal_rate": ("peak_gimbal_rate", max_gimbal_rate),
    }


def summarise(
    results: Results, scenario: str, duration_s: float, settle_deg: float, max_gimbal_rate: float
) -> dict[str, Any]:
    """The summary (JSON-ready) of ``results`` (see the module docstring)."""
    n = len(results)
    ok = results.ok
    metrics: dict[str, dict[str, float | int | None]] = {}
    for name in METRICS:
        readable = _readable(results, name)
        values = results.values.get(name, np.full(n, math.nan))[readable]
        counts = {"n": len(values), "left_out": int(ok.sum()) - len(values)}
        if len(values) == 0:
            metrics[name] = dict.fromkeys([*(f"p{p}" for p in PERCENTILES), "max", "mean"]) | counts
            continue
        # empirical quantiles (no interpolation: "never settled" runs are inf, and inf - inf is NaN)
        stats: dict[str, float | int | None] = {
            f"p{p}": float(np.percentile(values, p, method="inverted_cdf")) for p in PERCENTILES
        }
        stats["max"] = float(np.max(values))
        finite = values[np.isfinite(values)]
        stats["mean"] = float(np.mean(finite)) if len(finite) else None
        metrics[name] = stats | counts
    passes: dict[str, dict[str, Any]] = {}
    every = ok.copy()
    for req, (metric, limit) in requirements(duration_s, settle_deg, max_gimbal_rate).items():
        readable = _readable(results, metric)
        passed = readable & (results.values.get(metric, np.full(n, math.nan)) <= limit)
        every &= passed
        judged = {"metric": metric, "limit": limit, "not_judged": int((ok & ~readable).sum())}
        passes[req] = _rate(int(passed.sum()), n) | judged
    passes["all"] = _rate(int(every.sum()), n)
    worst = _worst(results)
    return {
        "scenario": scenario,
        "runs": n,
        "ok": int(ok.sum()),
        "failed": int(n - ok.sum()),
        "duration_s": duration_s,
        "metrics": metrics,
        "requirements": passes,
        "worst_final_error": worst,
        "failures": [{"index": i, "error": e} for i, e in sorted(results.errors.items())],
        "dropped_lines": results.dropped,
        **fault_figures(results),
    }


def _readable(results: Results, metric: str) -> Any:
    """(N,) bool: the ok runs whose ``metric`` is a value a run writes — a number, not empty or NaN, and
    not below zero where no run's can be (:data:`NON_NEGATIVE`). The one rule for both a metric's figures
    and a requirement's verdict: a figure no run measured is never counted as a pass."""
    values = results.values.get(metric, np.full(len(results), math.nan))
    readable = results.ok & ~np.isnan(values)
    if metric in NON_NEGATIVE:
        readable &= ~(values < 0)
    return readable


def fault_figures(results: Results) -> dict[str, Any]:
    """A fault campaign's figures ({} without ``[faults]``): faults injected by kind, the runs' exits,
    ``invariant_violations`` (invariant → violations over all runs) with the runs that broke each (up to
    10 indices) and their first message, detection latency and recovery time (s) p50 / p99 / max by
    kind and over all."""
    if "faults.list" not in results.text and "faults.n" not in results.values:
        return {}
    injected: dict[str, int] = {}
    for cell in results.text.get("faults.list", np.array([], dtype=str)):
        for fault in filter(None, str(cell).split(";")):
            kind = fault.split("@", 1)[0]
            injected[kind] = injected.get(kind, 0) + 1
    exits: dict[str, int] = {}
    for cell in results.text.get("exit", np.array([], dtype=str)):
        exits[str(cell)] = exits.get(str(cell), 0) + 1
    violations: dict[str, int] = {}
    broken: dict[str, list[int]] = {}
    for name in INVARIANTS:
        counts = results.values.get(f"inv.{name}", np.zeros(len(results)))
        violations[name] = int(np.nansum(counts))
        broken[name] = [int(i) for i in results.index[np.nan_to_num(counts) > 0][:10]]
    detection, dropped_detection = _by_kind(_cells(results, "detection.list"))
    recovery, dropped_recovery = _by_kind(_cells(results, "recovery.list"))
    first = results.text.get("inv.first", np.array([], dtype=str))
    examples = {int(results.index[k]): str(first[k]) for k in range(len(first)) if first[k]}
    return {
        "faults_injected": dict(sorted(injected.items())),
        "exits": exits,
        "invariant_violations": violations,
        "runs_with_violations": len(examples),
        "violating_runs": {name: runs for name, runs in broken.items() if runs},
        "first_violations": dict(list(examples.items())[:10]),
        "detection_s": detection,
        "recovery_s": recovery,
        "dropped_times": dropped_detection + dropped_recovery,
    }


def _by_kind(cells: Any) -> tuple[dict[str, dict[str, float | int]], int]:
    """``kind:seconds;...`` cells → p50 / p99 / max / n per kind and ``all``, and how many cells were
    dropped: a cell that is not what a run writes (an item without a kind or a colon, seconds that are not
    a finite number >= 0 — ``stall:abc``, ``stall:``) is dropped whole and counted, as read_runs drops a
    row with a metric that is no number; one was a ValueError's traceback from ``hil report``, every
    figure of the campaign lost with it."""
    values: dict[str, list[float]] = {}
    dropped = 0
    for cell in [] if cells is None else cells:
        times = _times(str(cell))
        if times is None:
            dropped += 1
            continue
        for kind, seconds in times:
            values.setdefault(kind, []).append(seconds)
            values.setdefault("all", []).append(seconds)
    out = {}
    for kind, v in sorted(values.items()):
        a = np.asarray(v)
        out[kind] = {
            "p50": float(np.percentile(a, 50)),
            "p99": float(np.percentile(a, 99)),
            "max": float(a.max()),
            "n": int(a.size),
        }
    return out, dropped


def _cells(results: Results, column: str) -> Any:
    """A ``kind:seconds;...`` column's cells, as written (read_runs reads it as text whatever its cells,
    :data:`~.store.TEXT_COLUMNS`: one that is a number, ``1.5``, is no time and is dropped and counted)."""
    return results.text.get(column)


def _times(cell: str) -> list[tuple[str, float]] | None:
    """The ``(kind, seconds)`` of one ``kind:seconds;...`` cell, or None when any item is not one."""
    times = []
    for item in filter(None, cell.split(";")):
        kind, colon, text = item.rpartition(":")
        try:
            seconds = float(text)
        except ValueError:
            return None
        if not colon or not kind or kind == "all" or not math.isfinite(seconds) or seconds < 0:
            return None
        times.append((kind, seconds))
    return times


def _rate(passed: int, n: int) -> dict[str, Any]:
    lo, hi = wilson_interval(passed, n)
    return {"passed": passed, "rate": passed / n if n else None, "ci95": [lo, hi]}


def wilson_interval(passed: int, n: int, z: float = 1.96) -> tuple[float | None, float | None]:
    """The Wilson score interval of a pass rate ``passed / n`` (None, None when n = 0)."""
    if n == 0:
        return None, None
    p = passed / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def _worst(results: Results, count: int = 5) -> list[dict[str, float]]:
    """The ``count`` ok runs with the largest final error: index and value."""
    final = results.values.get("final_error_deg")
    if final is None:
        return []
    idx = np.nonzero(results.ok & ~np.isnan(final))[0]
    order = idx[np.argsort(final[idx])[::-1][:count]]
    return [{"index": int(results.index[k]), "final_error_deg": float(final[k])} for k in order]


def format_table(summary: dict[str, Any]) -> str:
    """The summary as a text table (the CLI prints it)."""
    lines = [
        f"{summary['scenario']}: {summary['runs']} runs, {summary['ok']} ok, {summary['failed']} failed "
        f"({summary['duration_s']:g} s each)",
    ]
    lines += _completeness(summary)
    if summary["dropped_lines"]:
        lines.append(
            f"dropped          {summary['dropped_lines']} line(s) of runs.csv (damaged, a bad run index, "
            "or a run's earlier row): in no figure below"
        )
    lines += ["", f"{'metric':<20}" + "".join(f"{h:>12}" for h in ("p50", "p95", "p99", "max"))]
    for name, stats in summary["metrics"].items():
        cells = "".join(f"{_num(stats[k]):>12}" for k in ("p50", "p95", "p99", "max"))
        lines.append(f"{name:<20}{cells}")
    left_out = [
        f"{name} {stats['left_out']}" for name, stats in summary["metrics"].items() if stats["left_out"]
    ]
    if left_out:
        lines.append(
            "left out         ok runs without a value a run writes (empty, NaN, or below zero), not in "
            "that metric's figures: " + ", ".join(left_out)
        )
    lines += ["", f"{'requirement':<14}{'condition':<30}{'pass rate':>10}{'95% interval':>16}"]
    for name, req in summary["requirements"].items():
        condition = f"{req['metric']} <= {_num(req['limit'])}" if "metric" in req else "all of the above"
        rate = "-" if req["rate"] is None else f"{100 * req['rate']:.1f}%"
        lo, hi = req["ci95"]
        ci = "-" if lo is None else f"{100 * lo:.1f}-{100 * hi:.1f}%"
        unjudged = (
            f"  ({req['not_judged']} ok not judged: no readable value)" if req.get("not_judged") else ""
        )
        lines.append(f"{name:<14}{condition:<30}{rate:>10}{ci:>16}{unjudged}")
    if summary.get("too_short_to_judge"):
        lines.append(f"too short        {summary['too_short_to_judge']}: these verdicts are the duration's")
    if "invariant_violations" in summary:
        lines += [
            "",
            "faults injected  " + ", ".join(f"{k} {n}" for k, n in summary["faults_injected"].items()),
        ]
        lines.append("exits            " + ", ".join(f"{k} {n}" for k, n in summary["exits"].items()))
        total = sum(summary["invariant_violations"].values())
        lines.append(
            f"invariants       {total} violations, in {summary['runs_with_violations']} of "
            f"{summary['runs']} runs: "
            + ", ".join(f"{k} {n}" for k, n in summary["invariant_violations"].items())
        )
        for index, first in summary["first_violations"].items():
            lines.append(f"  run {index}: {first}")
        for name in ("detection_s", "recovery_s"):
            every = summary[name].get("all")
            if every:
                lines.append(
                    f"{name.split('_')[0]:<17}p50 {every['p50']:.3f} s  p99 {every['p99']:.3f} s  "
                    f"max {every['max']:.3f} s  ({every['n']})"
                )
        if summary.get("dropped_times"):
            lines.append(f"unreadable       {summary['dropped_times']} detection/recovery cells (dropped)")
    if summary["failures"]:
        silent = sum(not f["error"] for f in summary["failures"])
        said = f"; {silent} with {NO_ERROR}" if silent else ""
        lines += ["", f"failed runs ({len(summary['failures'])}{said}):"]
        lines += [f"  run {f['index']}: {f['error'] or NO_ERROR}" for f in summary["failures"][:10]]
        if len(summary["failures"]) > 10:
            lines.append(f"  ... {len(summary['failures']) - 10} more in summary.json")
    return "\n".join(lines)


def _completeness(summary: dict[str, Any]) -> list[str]:
    """The lines that say a campaign is not whole: partial (fewer of the runs asked on disk than were
    asked, or its last session did not finish: ``interrupted``), or its runs asked unknown (a campaign.json
    written before they were recorded: ``runs_asked`` None). None for a whole campaign, or a summary made
    without its directory (:func:`summarise` alone says neither)."""
    partial = summary.get("interrupted")
    if isinstance(partial, dict):
        asked = partial.get("runs_asked")
        on_disk = partial.get("runs_asked_on_disk", partial.get("runs_on_disk"))
        ended = f" (its last session: {str(partial['ended'])[:200]})" if partial.get("ended") else ""
        return [
            f"PARTIAL          interrupted: {on_disk} runs on disk of {str(asked)[:20]} asked{ended}: not a "
            "whole campaign's figures; the same command runs the rest"
        ]
    if "runs_asked" in summary and summary["runs_asked"] is None:
        return [
            "runs asked       unknown (campaign.json written before hil recorded them): whether the "
            "campaign is whole cannot be told"
        ]
    return []


def _num(x: float | None) -> str:
    if x is None:
        return "-"
    if math.isinf(x):
        return "inf"
    return f"{x:.4g}"
