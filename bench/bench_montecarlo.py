"""Monte Carlo campaigns on Dask through the full board + protocol loop: runs per minute on this machine
with 1 and 2 worker processes, each against a peer measured in the same run.

Every figure runs the same campaign (cubesat-1u with the default dispersions, shortened runs) from the
same seed; every run is :func:`hil.runtime.run` in lockstep (host, emulated board and protocol, world):

- plain loop: :func:`hil.montecarlo.run_chunk` called in this process over the campaign's runs, nothing
  else (no cluster, no files) — a run's own cost;
- Dask, 1 and 2 workers, ``batch`` runs per task: :func:`hil.montecarlo.run_campaign` on a LocalCluster of
  worker processes (started before the clock starts; its start-up is its own figure), i.e. submission,
  pickling, scheduling, streaming every run to disk, the summary;
- Dask, 2 workers, one run per task: whether batching runs per task still pays, now that a worker runs
  a chunk's runs one after another (no batch axis any more: only Dask's per-task cost is amortised);
- the Dask path's overhead per run: (Dask with 1 worker − plain loop) / runs;
- LocalCluster start-up: until every worker answers with the model imported.
"""

from __future__ import annotations

import importlib
import os
import tempfile
import time
from dataclasses import replace

from bench.common import Result

NAME = "montecarlo"


def _campaign(quick: bool, batch: int | None = None):  # type: ignore[no-untyped-def]
    from hil.montecarlo import Campaign, load_dispersions
    from hil.scenario import load_scenario

    base = load_scenario("cubesat-1u")
    scenario = base.with_changes(slew=replace(base.slew, duration_s=0.5 if quick else 10.0))
    if quick:
        scenario = scenario.with_changes(loop=replace(scenario.loop, warmup_s=0.5))
    runs, default_batch = (4, 2) if quick else (16, 4)
    return Campaign(
        scenario, load_dispersions("default", scenario), runs=runs, seed=1, batch=batch or default_batch
    )


def _plain(campaign) -> float:  # type: ignore[no-untyped-def]
    """Wall seconds of run_chunk over every run of the campaign, in this process."""
    from hil.montecarlo import run_chunk

    runs = [campaign.draw(i) for i in range(campaign.runs)]
    start = time.perf_counter()
    results = run_chunk(campaign.scenario, runs, campaign.trace_hz)
    assert all(r.ok for r in results), [r.error for r in results if not r.ok]
    return time.perf_counter() - start


def _dask(campaign, workers: int) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """(cluster start-up s, campaign wall s) on a LocalCluster of ``workers`` processes."""
    from hil.montecarlo import open_client, run_campaign

    start = time.perf_counter()
    with open_client(workers=workers) as client, tempfile.TemporaryDirectory() as out:
        client.run(importlib.import_module, "hil.montecarlo.runner")  # workers up, the model imported
        client.run(importlib.import_module, "firmware_sim.world")
        ready = time.perf_counter()
        report = run_campaign(campaign, out, client, plots=False)
        assert report.failed == 0 and report.completed == campaign.runs, report.summary.get("failures")
        return ready - start, report.wall_s


def run(quick: bool) -> list[Result]:
    import logging

    import distributed  # noqa: F401 — configures its loggers on import

    logging.getLogger("distributed").setLevel(logging.WARNING)
    campaign = _campaign(quick)
    n, b = campaign.runs, campaign.batch
    sc = campaign.scenario
    sim = sc.slew.duration_s + sc.loop.warmup_s
    load = os.getloadavg()[0]
    plain = _plain(campaign)
    startup_1, dask_1 = _dask(campaign, 1)
    startup_2, dask_2 = _dask(campaign, 2)
    _, dask_2_single = _dask(_campaign(quick, batch=1), 2)
    per_min = 60.0 * n
    note = (
        f"{n} runs of {sim:g} s simulated (warm-up + slew; plus the spin-up) through host, board, protocol "
        f"and world; load average {load:.2f} on {os.cpu_count()} CPUs at the start"
    )
    return [
        Result(NAME, "plain loop (run_chunk, this process)", per_min / plain, "runs/min", note=note),
        Result(NAME, f"Dask LocalCluster, 1 worker, batch {b}", per_min / dask_1, "runs/min", "plain loop",
               per_min / plain),
        Result(NAME, f"Dask LocalCluster, 2 workers, batch {b}", per_min / dask_2, "runs/min",
               "Dask, 1 worker", per_min / dask_1, note="2 cores shared with the rest of the machine"),
        Result(NAME, f"Dask LocalCluster, 2 workers, batch {b}", per_min / dask_2, "runs/min",
               "Dask, 2 workers, batch 1", per_min / dask_2_single,
               note="what batching runs per Dask task still buys"),
        Result(NAME, "Dask path overhead per run", 1e3 * (dask_1 - plain) / n, "ms/run",
               "plain loop, per run", 1e3 * plain / n, higher_is_better=False,
               note="(Dask 1 worker - plain loop) / runs; the peer column is a run's own cost"),
        Result(NAME, "LocalCluster start-up, 1 worker", startup_1, "s", higher_is_better=False),
        Result(NAME, "LocalCluster start-up, 2 workers", startup_2, "s", higher_is_better=False),
    ]  # fmt: skip


if __name__ == "__main__":
    for row in run(quick=False):
        print(row)
