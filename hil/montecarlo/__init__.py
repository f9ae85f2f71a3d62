"""Monte Carlo campaigns: dispersed lockstep runs of a scenario through the one closed loop (host, emulated
board, world: :func:`hil.runtime.run`), scaled out on Dask (docs/montecarlo.md). ``dispersions`` (TOML
dispersion files, per-run draws), ``runner`` (a run's scenario from its draws; a worker's chunk of runs),
``metrics``, ``store`` (the output directory, written run by
run), ``campaign`` (the Dask driver), ``summary`` and ``plots``."""

from .campaign import Campaign, CampaignReport, open_client, run_campaign, runs_left, summarise_dir
from .dispersions import Dispersions, RunParams, draw, load_dispersions, parse_dispersions
from .metrics import METRICS, TRACES
from .runner import RunResult, run_chunk
from .store import Results, read_runs, read_traces

__all__ = [
    "METRICS",
    "TRACES",
    "Campaign",
    "CampaignReport",
    "Dispersions",
    "Results",
    "RunParams",
    "RunResult",
    "draw",
    "load_dispersions",
    "open_client",
    "parse_dispersions",
    "read_runs",
    "read_traces",
    "run_campaign",
    "run_chunk",
    "runs_left",
    "summarise_dir",
]
