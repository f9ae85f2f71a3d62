"""``hil montecarlo``: a Monte Carlo campaign of dispersed lockstep runs through the one closed loop (host,
emulated board, world), on Dask."""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from typing import TYPE_CHECKING, Any, TextIO

from hil.cli._parser import given_path
from hil.numbers import MAX_SEED

if TYPE_CHECKING:
    from hil.montecarlo import CampaignReport

ORDER = 20

EXIT_OK = 0
EXIT_RUNS_FAILED = 1
"""At least one run in the output directory failed (every run failing included). Status 2 is an error in
the options or files (the ``hil`` entry point's, for every command), 130 an interrupt."""

EPILOG = """\
examples:
  hil montecarlo cubesat-1u --runs 200                     # all cores, default dispersions, seed = scenario's
  hil montecarlo cubesat-1u --runs 200 --out mc/c1         # Ctrl-C, then the same command finishes the rest
  hil montecarlo cubesat-1u --runs 1000 --out mc/c1        # ... or asks for 800 more runs of that campaign
  hil montecarlo paper-testbed --runs 50 --seed 7 --dispersions my-dispersions.toml
  hil montecarlo cubesat-1u --runs 20 --duration 10 --workers 1 --batch 4   # a quick look
  hil montecarlo cubesat-1u --runs 5000 --scheduler tcp://10.0.0.5:8786     # a running Dask cluster

  # a cluster of your own: `dask scheduler` on one machine, `dask worker tcp://HOST:8786 --nthreads 1`
  # on each (same Python environment with vscmg-hil installed), then --scheduler tcp://HOST:8786

writes OUT/runs.csv (one row per run: index, status, error, dispersed parameters, metrics; flushed as
each run finishes), traces.bin (decimated error traces), campaign.json, summary.json and plots/.
Dispersion files: fixtures/dispersions/ (default.toml documents the format).

A Dask worker lost mid-campaign (its process died) is reported on stderr as it happens; Dask reruns its
chunks elsewhere, and the closing line counts the lost workers. A cluster left with no worker for 60 s
(all killed, or each unable to load the campaign's task: a Python without vscmg-hil) ends the command,
status 2, the runs done kept (Dask's distributed.scheduler.no-workers-timeout sets the wait).

exit status:
  0    every run in OUT finished ok (and, with [faults], kept every invariant)
  1    at least one run in OUT failed (every run failing included; a resumed campaign counts the
       failures the directory already held), or violated an invariant of the fault campaign (a run
       that misses its requirement because of a fault, and says so, is not a violation)
  2    an error in the options or the files (nothing, or nothing more, is run)
  130  interrupted (Ctrl-C): the finished runs are on disk; the same command finishes the rest
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "montecarlo",
        help="Monte Carlo campaign: dispersed lockstep closed-loop runs on Dask",
        description="Run N lockstep closed-loop runs of a scenario with dispersed parameters (each run's "
        "parameters from the seed and its index) on a Dask LocalCluster or a running Dask scheduler; "
        "results are written run by run, so an interrupted campaign resumes where it stopped.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scenario", metavar="SCENARIO", help="a shipped scenario name or a scenario TOML file")
    p.add_argument(
        "--runs", type=int, required=True, metavar="N", help="number of runs (indices 0..N-1; at most 10^7)"
    )
    p.add_argument("--seed", type=int, metavar="S", help="campaign seed (default: the scenario's seed)")
    p.add_argument(
        "--dispersions", metavar="FILE", help="dispersion TOML file or shipped name (default: default)"
    )
    p.add_argument(
        "--scheduler", metavar="ADDRESS", help="a running Dask scheduler (default: a LocalCluster)"
    )
    p.add_argument(
        "--workers",
        type=int,
        metavar="W",
        help="LocalCluster worker processes (default: all cores; at most 4 a core, and no more than the "
        "runs' tasks)",
    )
    p.add_argument(
        "--batch", type=int, default=4, metavar="B", help="runs per Dask task, one after another (4)"
    )
    p.add_argument(
        "--out", type=given_path, metavar="DIR", help="output directory (default: runs/<stamp>-mc-<name>)"
    )
    p.add_argument(
        "--board",
        choices=("emulator", "firmware"),
        help="each run's board: the Python emulator (the default) or the firmware ELF under simavr "
        "(make -C firmware; emu://?board=firmware)",
    )
    p.add_argument("--duration", type=float, metavar="S", help="each run this long after the slew starts")
    p.add_argument("--trace-hz", type=float, default=5.0, metavar="HZ", help="stored error traces' rate (5)")
    p.add_argument("--no-plots", action="store_true", help="skip the plots")
    p.set_defaults(func=run)


class ProgressBar:
    """One line on stderr: a bar, runs done of total, failures, runs per minute and the time left."""

    def __init__(self, stream: TextIO | None = None, width: int = 30) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.width = width
        self.start = time.monotonic()
        self.first: int | None = None
        self.failed = 0
        self.line = ""  # the bar as last drawn: a note covers it, then draws it again below

    def __call__(self, result: Any, done: int, total: int) -> None:
        if self.first is None:
            self.first = done - 1
        self.failed += not result.ok
        fill = int(self.width * done / total)
        elapsed = time.monotonic() - self.start
        rate = (done - self.first) / elapsed * 60.0 if elapsed > 0 else math.nan
        left = (total - done) / rate * 60.0 if rate > 0 else math.nan
        eta = "-" if not math.isfinite(left) else f"{int(left // 60)}m{int(left % 60):02d}s"
        line = (
            f"[{'#' * fill}{'.' * (self.width - fill)}] {done}/{total} runs  {self.failed} failed  "
            f"{rate:6.1f} runs/min  ETA {eta}   "
        )
        self.stream.write(f"\r{line}")
        self.line = line
        self.stream.flush()

    def note(self, line: str) -> None:
        """A line of its own above the bar (a lost worker), as it happens; the bar goes on below it."""
        self.stream.write(f"\r{line.ljust(len(self.line))}\n{self.line}")
        self.stream.flush()

    def close(self) -> None:
        self.stream.write("\n")
        self.stream.flush()


def exit_status(report: CampaignReport) -> tuple[int, str]:
    """The command's exit status for a finished campaign, and why when it is not 0: the one place that
    decides it (see ``EPILOG``). Counted over every run in the output directory (``report.summary``), so
    that running the command again on a campaign with failures does not turn it into a success."""
    summary = report.summary
    if summary.get("failed", 0):
        return EXIT_RUNS_FAILED, f"{summary['failed']} of {summary['runs']} runs failed"
    broken = summary.get("runs_with_violations", 0)
    if broken:
        return EXIT_RUNS_FAILED, f"{broken} of {summary['runs']} runs violated an invariant"
    return EXIT_OK, ""


def closing_line(report: CampaignReport) -> str:
    """What the session did: runs, time, workers (and those lost), the rate, where the results are."""
    workers = f"{report.workers} worker{'' if report.workers == 1 else 's'}"
    lost = report.workers_lost
    if lost:
        noun = "worker" if lost == 1 else "workers"
        if report.workers_joined >= lost:
            workers += f", {lost} {noun} lost and restarted"
        else:
            workers += f", {lost} {noun} lost ({report.workers_joined} restarted)"
    return (
        f"{report.completed} runs in {report.wall_s:.1f} s on {workers} "
        f"({report.runs_per_minute:.1f} runs/min); results in {report.out_dir}"
    )


WORKERS_PER_CORE = 4
"""The most LocalCluster worker processes ``--workers`` may ask for, per core this process may use: a
run is CPU-bound, so workers beyond the cores only share them, while each holds its own interpreter and
kernels (~150 MB) and takes its turn to start — 1 000 asked of a 2-core machine took minutes only to
start, and could exhaust its memory. A Dask scheduler (``--scheduler``) spreads a campaign further."""


def check_options(args: argparse.Namespace) -> None:
    """The numbers on the command line within their documented bounds (``--runs`` 1..10⁷, ``--batch``
    1..10⁴, ``--workers`` 1..:data:`WORKERS_PER_CORE` × the cores, ``--seed`` 0..2⁶³−1), before anything
    is read or started: one :class:`ConfigError` naming the option."""
    from hil.cores import available_cores
    from hil.montecarlo.campaign import MAX_BATCH, MAX_RUNS
    from protocol.errors import ConfigError

    cores = available_cores()
    bounds = {
        "runs": (1, MAX_RUNS, ""),
        "batch": (1, MAX_BATCH, ""),
        "workers": (
            1,
            WORKERS_PER_CORE * cores,
            f" ({WORKERS_PER_CORE} a core on this machine's {cores}: more only share the cores; "
            "a Dask scheduler, --scheduler, spreads further)",
        ),
        "seed": (0, MAX_SEED, ""),
    }
    for name, (lo, hi, why) in bounds.items():
        value = getattr(args, name)
        if value is not None and not lo <= value <= hi:
            raise ConfigError(f"must be an integer in {lo}..{hi}, got {value}{why}", f"--{name}")


def local_workers(args: argparse.Namespace) -> int | None:
    """The LocalCluster's worker processes: ``--workers`` (default: one per core), but no more than the
    campaign has tasks (``--runs`` over ``--batch``) — a worker with nothing to run only costs its start;
    None with ``--scheduler`` (its workers are its own)."""
    from hil.cores import available_cores

    if args.scheduler is not None:
        return args.workers  # refused beside a scheduler by open_client, naming it
    tasks = -(-args.runs // args.batch)
    return min(args.workers if args.workers is not None else available_cores(), tasks)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    import distributed  # noqa: F401 — configures its loggers on import; quieten them after

    from hil.montecarlo import Campaign, load_dispersions, open_client, run_campaign, runs_left
    from hil.montecarlo.summary import format_table
    from hil.runtime.runlog import new_run_dir
    from hil.scenario import load_scenario
    from hil.scenario.reader import check_run_length
    from protocol.errors import ConfigError

    if not args.verbose:  # Dask's scheduler logs every worker's comings and goings at INFO
        logging.getLogger("distributed").setLevel(logging.WARNING)
        # and its client a traceback for each try to reach a scheduler that is gone: the campaign says so
        # itself, naming the scheduler and the runs left (hil.montecarlo.campaign)
        logging.getLogger("distributed.client").setLevel(logging.CRITICAL)
    check_options(args)
    scenario = load_scenario(args.scenario).with_board(args.board)
    if args.duration is not None:
        if not (math.isfinite(args.duration) and args.duration > 0):
            raise ConfigError(f"must be positive, got {args.duration}", "--duration")
        loop = scenario.loop
        check_run_length(loop.warmup_s, args.duration, loop.plant_step_s, "--duration")
        scenario = scenario.with_changes(slew=replace(scenario.slew, duration_s=args.duration))
    dispersions = load_dispersions(args.dispersions, scenario)
    try:
        campaign = Campaign(
            scenario,
            dispersions,
            args.runs,
            scenario.seed if args.seed is None else args.seed,
            args.batch,
            args.trace_hz,
        )
    except ConfigError as exc:  # the campaign's field as the option that set it
        option = {"campaign.trace_hz": "--trace-hz"}.get(exc.where)
        if option is None:
            raise
        raise ConfigError(exc.detail, option) from None
    # said once every option is taken, before the runs start: not found in their verdicts afterwards
    needed = scenario.time_to_judge()
    shortfall = needed.shortfall(scenario.slew.duration_s)
    if shortfall is not None:
        print(
            f"hil montecarlo: warning: {shortfall}: the settle and final_error verdicts will be the "
            "duration's, and a fault campaign does not count such a miss against back_in_control "
            f"(--duration {math.ceil(needed.total_s)} or more judges them)",
            file=sys.stderr,
        )
    bar = ProgressBar()
    what = (
        f"{campaign.runs} runs of {scenario.name} ({scenario.slew.duration_s:g} s each, "
        f"dispersions {dispersions.where}, seed {campaign.seed})"
    )
    if args.out is not None and runs_left(campaign, args.out) == 0:  # a finished campaign again: no cluster
        out = args.out
        print(f"hil montecarlo: {what}: all in {out} already; summarised again, no cluster", file=sys.stderr)
        report = run_campaign(campaign, out, None, plots=not args.no_plots)
    else:
        with open_client(args.scheduler, local_workers(args)) as client:
            out = args.out if args.out is not None else new_run_dir("runs", f"mc-{scenario.name}")
            where = f"scheduler {args.scheduler}" if args.scheduler else "a local cluster"
            print(f"hil montecarlo: {what} on {where} -> {out}", file=sys.stderr)
            try:
                report = run_campaign(
                    campaign,
                    out,
                    client,
                    on_result=bar,
                    plots=not args.no_plots,
                    on_worker_lost=lambda loss: bar.note(f"hil montecarlo: {loss.describe()}"),
                )
            finally:
                bar.close()
    if report.skipped:
        print(
            f"{report.skipped} runs were already in {out}; ran the other {report.completed}", file=sys.stderr
        )
    print(format_table(report.summary))
    print(f"\n{closing_line(report)}")
    status, why = exit_status(report)
    if status != EXIT_OK:
        print(f"hil montecarlo: {why} (exit status {status})", file=sys.stderr)
    return status
