"""Monte Carlo campaigns on Dask: runs per minute on this machine with 1 and 2 worker processes, and the
cost of the Dask path against a plain in-process loop over the same runs (the peer), measured in one run.

Every figure runs the same campaign (cubesat-1u with the default dispersions, shortened runs) from the
same seed:

- plain loop, batch 1 and batch B: :func:`hil.montecarlo.run_chunk` called in this process over the
  campaign's chunks, nothing else (no cluster, no files) — what batching the runs on the plant's batch
  axis buys;
- Dask, 1 and 2 workers: :func:`hil.montecarlo.run_campaign` on a LocalCluster of worker processes
  (started before the clock starts; its start-up is its own figure), i.e. submission, pickling,
  scheduling, streaming every run to disk, the summary;
- the Dask path's overhead per run: (Dask with 1 worker − plain loop with batch B) / runs;
- LocalCluster start-up: until every worker answers with the model imported.
"""

from __future__ import annotations

import importlib
import tempfile
import time
from dataclasses import replace

from bench.common import Result

NAME = "montecarlo"


def _campaign(quick: bool):  # type: ignore[no-untyped-def]
    from hil.montecarlo import Campaign, load_dispersions
    from hil.scenario import load_scenario

    base = load_scenario("cubesat-1u")
    scenario = base.with_changes(slew=replace(base.slew, duration_s=0.5 if quick else 10.0))
    if quick:
        scenario = scenario.with_changes(loop=replace(scenario.loop, warmup_s=0.5))
    runs, batch = (4, 2) if quick else (24, 6)
    return Campaign(scenario, load_dispersions("default", scenario), runs=runs, seed=1, batch=batch)


def _plain(campaign, batch: int) -> float:  # type: ignore[no-untyped-def]
    """Wall seconds of run_chunk over the campaign's chunks of ``batch``, in this process."""
    from hil.montecarlo import run_chunk
    from hil.montecarlo.campaign import chunks

    start = time.perf_counter()
    for chunk in chunks(list(range(campaign.runs)), batch, 1):
        results = run_chunk(campaign.scenario, [campaign.draw(i) for i in chunk], campaign.trace_hz)
        assert all(r.ok for r in results), [r.error for r in results if not r.ok]
    return time.perf_counter() - start


def _dask(campaign, workers: int) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """(cluster start-up s, campaign wall s) on a LocalCluster of ``workers`` processes."""
    from hil.montecarlo import open_client, run_campaign

    start = time.perf_counter()
    with open_client(workers=workers) as client, tempfile.TemporaryDirectory() as out:
        client.run(importlib.import_module, "hil.montecarlo.runner")  # workers up, the model imported
        ready = time.perf_counter()
        report = run_campaign(campaign, out, client, plots=False)
        assert report.failed == 0 and report.completed == campaign.runs
        return ready - start, report.wall_s


def run(quick: bool) -> list[Result]:
    import logging

    import distributed  # noqa: F401 — configures its loggers on import

    logging.getLogger("distributed").setLevel(logging.WARNING)
    campaign = _campaign(quick)
    n, b = campaign.runs, campaign.batch
    sim = campaign.scenario.slew.duration_s + campaign.scenario.loop.warmup_s
    plain_1 = _plain(campaign, 1)
    plain_b = _plain(campaign, b)
    startup_1, dask_1 = _dask(campaign, 1)
    startup_2, dask_2 = _dask(campaign, 2)
    per_min = 60.0 * n
    note = f"{n} runs of {sim:g} s simulated (warm-up + slew), estimator in the loop"
    return [
        Result(NAME, f"plain loop, batch {b}", per_min / plain_b, "runs/min", "plain loop, batch 1",
               per_min / plain_1, note=f"vectorised runs on the plant's batch axis; {note}"),
        Result(NAME, "Dask LocalCluster, 1 worker", per_min / dask_1, "runs/min", f"plain loop, batch {b}",
               per_min / plain_b, note=f"batch {b}; {note}"),
        Result(NAME, "Dask LocalCluster, 2 workers", per_min / dask_2, "runs/min", "Dask, 1 worker",
               per_min / dask_1, note=f"batch {b}, 2 cores shared with the rest of the machine"),
        Result(NAME, "Dask path overhead per run", 1e3 * (dask_1 - plain_b) / n, "ms/run",
               "plain loop, per run", 1e3 * plain_b / n, higher_is_better=False,
               note="(Dask 1 worker - plain loop) / runs; the peer column is a run's own cost"),
        Result(NAME, "LocalCluster start-up, 1 worker", startup_1, "s", higher_is_better=False),
        Result(NAME, "LocalCluster start-up, 2 workers", startup_2, "s", higher_is_better=False),
    ]  # fmt: skip


if __name__ == "__main__":
    for row in run(quick=False):
        print(row)
