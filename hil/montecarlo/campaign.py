"""Monte Carlo campaigns on Dask: N dispersed lockstep runs of a scenario through the one closed loop (the
host, the emulated board and its protocol, the world: :func:`hil.runtime.run`), on a
``dask.distributed`` cluster — a LocalCluster on this machine (one single-threaded worker process per core)
or any running scheduler given by address. Both take the same path: :func:`run_campaign` gets a
:class:`distributed.Client` and never asks which kind it is.

The driver draws each run's parameters (:func:`~.dispersions.draw`: a pure function of seed and index),
skips the runs the output directory already holds, and submits chunks of ``batch`` runs; a worker runs a
chunk's runs one after another (:func:`~.runner.run_chunk`: a chunk amortises Dask's per-task cost over
its runs). Finished chunks are
taken as they complete (``as_completed``) and each run is written to disk at once
(:class:`~.store.ResultStore`), so Ctrl-C or a crash loses no finished run. A chunk whose worker died
(Dask retries it elsewhere first) is recorded as failed runs with the error, never dropped.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil.runtime.runlog import write_summary
from hil.scenario import Scenario
from protocol.errors import ConfigError, LinkError

from .dispersions import Dispersions, RunParams, draw
from .metrics import trace_length
from .runner import RunResult, describe, run_chunk
from .store import ResultStore, manifest, read_runs
from .summary import summarise

logger = logging.getLogger(__name__)

DEFAULT_BATCH = 4  # runs per Dask task: spreads Dask's per-task cost, keeps the workers balanced
DEFAULT_TRACE_HZ = 5.0


@dataclass(frozen=True)
class Campaign:
    """What to run: ``runs`` runs (indices 0..runs-1) of ``scenario`` (its slew's ``duration_s`` is each
    run's length) under ``dispersions``, from ``seed``; ``batch`` runs per Dask task (run one after another);
    ``trace_hz`` the rate of the stored error traces."""

    scenario: Scenario
    dispersions: Dispersions
    runs: int
    seed: int
    batch: int = DEFAULT_BATCH
    trace_hz: float = DEFAULT_TRACE_HZ

    def __post_init__(self) -> None:
        for name in ("runs", "batch"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ConfigError(f"must be a positive integer, got {value!r}", f"campaign.{name}")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"must be a non-negative integer, got {self.seed!r}", "campaign.seed")
        rate = self.scenario.loop.control_rate_hz
        if not (math.isfinite(self.trace_hz) and 0 < self.trace_hz <= rate):
            raise ConfigError(f"must be in (0, {rate:g}] Hz (the control rate)", "campaign.trace_hz")
        if self.dispersions.scenario is not self.scenario:
            raise ConfigError("the dispersions are bound to another scenario", "campaign.dispersions")

    def draw(self, index: int) -> RunParams:
        return draw(self.dispersions, self.seed, index)

    def manifest(self) -> dict[str, Any]:
        sc = self.scenario
        return manifest(
            sc.name, sc.source, self.dispersions.text, self.seed, sc.slew.duration_s, self.trace_hz,
            trace_length(sc.slew.duration_s, self.trace_hz), self.dispersions.columns(),
        )  # fmt: skip


@dataclass
class CampaignReport:
    """How a session went: ``skipped`` runs were already in the directory, ``completed`` finished now (of
    them ``failed`` with an error) in ``wall_s`` on ``workers`` worker threads; ``summary`` covers every run
    in the directory."""

    out_dir: Path
    runs: int
    skipped: int
    completed: int
    failed: int
    wall_s: float
    workers: int
    summary: dict[str, Any] = field(default_factory=dict)
    plots: dict[str, Path] = field(default_factory=dict)

    @property
    def runs_per_minute(self) -> float:
        return 60.0 * self.completed / self.wall_s if self.wall_s > 0 else math.nan


@contextmanager
def open_client(
    scheduler: str | None = None, workers: int | None = None, processes: bool = True, timeout_s: float = 10.0
) -> Iterator[Any]:
    """A :class:`distributed.Client`: on the running scheduler at ``scheduler`` (``tcp://host:8786``), or
    on a LocalCluster of ``workers`` single-threaded workers (default: one per core), as processes (or
    threads of this process with ``processes=False``: for tests and debugging). Closed on exit."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        if workers is not None:
            raise ConfigError("--workers is for a local cluster; a scheduler has its own workers", "workers")
        try:
            client = Client(scheduler, timeout=timeout_s)
        except (OSError, TimeoutError) as exc:
            raise LinkError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from exc
        with client:
            yield client
        return
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise ConfigError(f"must be at least 1, got {n}", "workers")
    with (
        LocalCluster(
            n_workers=n, threads_per_worker=1, processes=processes, dashboard_address="127.0.0.1:0",
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):  # fmt: skip
        yield client


def chunks(indices: Sequence[int], batch: int, workers: int) -> list[list[int]]:
    """``indices`` in consecutive chunks of at most ``batch``, smaller when there are too few runs to keep
    every worker busy (then each worker gets about one chunk)."""
    if not indices:
        return []
    size = max(1, min(batch, math.ceil(len(indices) / max(workers, 1))))
    return [list(indices[k : k + size]) for k in range(0, len(indices), size)]


def run_campaign(
    campaign: Campaign,
    out_dir: str | os.PathLike[str],
    client: Any,
    on_result: Callable[[RunResult, int, int], None] | None = None,
    plots: bool = True,
) -> CampaignReport:
    """Run the campaign's missing runs on ``client`` into ``out_dir`` (created, or resumed: see the module
    docstring), then write ``summary.json`` and the plots. ``on_result(result, done, total)`` is called
    after each run is on disk (the CLI's progress bar). KeyboardInterrupt cancels the pending work and
    propagates; every run finished by then is on disk."""
    from distributed import as_completed

    out = Path(out_dir)
    start = time.perf_counter()
    workers = max(1, sum(client.nthreads().values()))
    completed = failed = 0
    with ResultStore(out, campaign.manifest()) as store:
        todo = [i for i in range(campaign.runs) if i not in store.finished]
        skipped = campaign.runs - len(todo)
        pending: dict[Any, list[RunParams]] = {}
        try:
            for chunk in chunks(todo, campaign.batch, workers):
                runs = [campaign.draw(i) for i in chunk]
                future = client.submit(run_chunk, campaign.scenario, runs, campaign.trace_hz, pure=False)
                pending[future] = runs
            for future in as_completed(list(pending)):
                runs = pending.pop(future)
                try:
                    results = future.result()
                except Exception as exc:  # the worker died or the task was lost: record, never drop
                    results = [RunResult.failed(r, f"chunk lost: {describe(exc)}") for r in runs]
                for result in results:
                    store.append(result)
                    completed += 1
                    failed += not result.ok
                    if on_result is not None:
                        on_result(result, skipped + completed, campaign.runs)
                store.sync()
        except BaseException:
            client.cancel(list(pending))
            raise
    report = CampaignReport(
        out, campaign.runs, skipped, completed, failed, time.perf_counter() - start, workers
    )
    report.summary = summarise_dir(out, campaign.scenario)
    if plots:
        from .plots import plot_campaign

        sc = campaign.scenario
        report.plots = plot_campaign(out, sc.settle_deg, sc.spacecraft.limits.max_gimbal_rate)
    return report


def summarise_dir(out_dir: str | os.PathLike[str], scenario: Scenario) -> dict[str, Any]:
    """Summarise every run in ``out_dir`` against ``scenario``'s requirements and write summary.json."""
    sc = scenario
    summary = summarise(
        read_runs(out_dir), sc.name, sc.slew.duration_s, sc.settle_deg, sc.spacecraft.limits.max_gimbal_rate
    )
    write_summary(out_dir, summary)
    return summary
