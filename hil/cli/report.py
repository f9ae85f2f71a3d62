"""``hil report``: (re)draw the plots of a run directory or a Monte Carlo campaign and print its summary."""

from __future__ import annotations

import argparse
import math
import sys
from contextlib import ExitStack
from pathlib import Path

ORDER = 15

EPILOG = """\
examples:
  hil report runs/20261124-101500-cubesat-1u        # a `hil run` directory: its plots/ again, its summary
  hil report runs/*-cubesat-1u                      # several at once
  hil report mc/c1                                  # a `hil montecarlo` campaign: histograms, envelopes,
                                                    # scatter of the dispersed parameters, pass rates

A run directory is recognised by telemetry.csv, a campaign by campaign.json. Plots go to DIR/plots/ (the
files a run or campaign wrote are replaced); a run that was killed, or is still running (which of the
two is said), is reported up to its last flushed row, one that ended before its first row (a port that
could not be opened) without plots, a figure it never measured as "-". Every DIR given is reported: one
that cannot be (not a run or a campaign, damaged files — a run's summary.json too, its rows and plots
reported all the same —, plots that cannot be written) is an error on stderr naming it, the next DIR
reported all the same, and the exit status is then 2.

exit status:
  0    every DIR reported, and every campaign among them whole (each of the runs its last session asked
       for on disk; one whose runs asked are unknown, from before hil recorded them, cannot be told)
  2    a DIR could not be reported (above)
  3    every DIR reported, but one among them is not whole: a campaign PARTIAL (interrupted, stopped,
       killed, or still running: fewer of its runs asked on disk than were asked; the same `hil montecarlo`
       command runs the rest), or a run without its summary.json (killed, or still running: its rows so
       far). A script or CI job that gates on `hil report` is told its figures are not the whole's

A campaign a session is writing is reported from its runs so far; its summary.json and plots are left to
that session (written only under the directory's lock, as the session writes them).
"""

EXIT_OK = 0
EXIT_NOT_REPORTED = 2
EXIT_PARTIAL = 3
"""Every directory reported, one among them not whole — a campaign partial, a run without its summary
(killed, or still running) —: its printed figures are not the whole's. Status 0 it was, and ``hil report
mc/c1 && publish`` published the figures of 3 runs of 40 as the campaign's (the table said PARTIAL; the
status said whole); a run killed 10 s into its 40 s was reported "0" as a finished one."""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "report",
        help="redraw a run's (or a Monte Carlo campaign's) plots and print its summary",
        description="Redraw the figures of a `hil run` directory or a `hil montecarlo` campaign from the "
        "files it wrote, and print its summary.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("dirs", nargs="+", type=Path, metavar="DIR", help="run directory or campaign directory")
    p.add_argument("--no-plots", action="store_true", help="print the summary only")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Report each directory in turn: :data:`EXIT_NOT_REPORTED` if any could not be, else
    :data:`EXIT_PARTIAL` if one among them is not whole (a campaign, a run), else :data:`EXIT_OK`. A
    directory that cannot be reported is said as the command says any error (``hil report: error: ...``,
    stderr) and the next one is reported: ``hil report runs/*`` once stopped at the first such directory,
    the rest never reported. One not whole is said on stderr too, with the status."""
    from protocol.errors import HilError

    failed = partial = 0
    for i, path in enumerate(args.dirs):
        if i:
            print()
        try:
            drawn = report(path, plots=not args.no_plots)
        except HilError as exc:
            sys.stdout.flush()  # its lines before the error, in order on a terminal showing both
            print(f"hil report: error: {exc}", file=sys.stderr)
            failed += 1
            continue
        if drawn.partial is not None:
            sys.stdout.flush()
            print(f"hil report: {path}: {drawn.partial}", file=sys.stderr)
            partial += 1
    if failed and len(args.dirs) > 1:
        print(f"hil report: {failed} of {len(args.dirs)} directories not reported", file=sys.stderr)
    if failed:
        return EXIT_NOT_REPORTED
    return EXIT_PARTIAL if partial else EXIT_OK


class Reported(dict[str, Path]):
    """What :func:`report` drew (plot name → path), and ``partial``: why the directory reported is not
    whole — a campaign (runs on disk of those asked, how its last session ended), a run (no summary.json:
    killed, or still running) —, or None."""

    partial: str | None = None


def report(path: Path, plots: bool = True) -> Reported:
    """Print ``path``'s summary and redraw its plots; returns name → plot path, and whether a campaign is
    partial (:class:`Reported`). A directory that is neither
    a run nor a campaign is an :class:`~protocol.errors.InputFormatError` naming it; so is a run whose
    summary.json is damaged (not JSON, truncated, values no run writes), raised after its rows are counted
    and whatever plots it allows are drawn."""
    from hil.montecarlo.store import MANIFEST
    from protocol.errors import InputFormatError

    damaged: dict[str, str] = {}
    drawn = Reported()
    if (path / "telemetry.csv").is_file():
        plotted, damaged, drawn.partial = _run_dir(path, plots)
        drawn.update(plotted)
    elif (path / MANIFEST).is_file():
        drawn = _campaign(path, plots)
    elif path.is_dir():
        raise InputFormatError(
            "neither a run directory (telemetry.csv) nor a Monte Carlo campaign (campaign.json)", str(path)
        )
    else:
        raise InputFormatError("no such directory", str(path))
    for name, file in drawn.items():
        print(f"  {name}: {file}")
    if damaged:
        # after what could be reported: a damaged summary.json is a run not wholly reported, as any damaged
        # file is (exit status 2) — it once exited 0, and ``hil report runs/* && …`` took it for whole
        (name, why), *more = damaged.items()
        also = "".join(f"; {other} damaged too ({reason})" for other, reason in more)
        raise InputFormatError(f"damaged ({why}){also}", str(path / name))
    return drawn


def _run_dir(path: Path, plots: bool) -> tuple[dict[str, Path], dict[str, str], str | None]:
    """Print the run directory ``path``'s counts and summary and draw its plots: name → plot path, its
    damaged files (said here on stdout too): file name → what is wrong with it (summary.json's values; a
    telemetry.csv of no readable row), and why the run is not whole (no summary.json: killed, or still
    running), or None."""
    from hil.cli.run import UNREADABLE, checked_summary
    from hil.cores import available_cores
    from hil.plots.run import not_units, plot_run
    from hil.plots.streamed import Gaps
    from hil.runtime.runlog import TelemetryBlocks, count_events, read_summary
    from protocol.errors import InputFormatError
    from protocol.messages import MAX_UNITS

    # its rows counted and their times looked at, nothing kept (the plots read the columns they draw): its
    # header checked, a run's; a time gap (a run that stalled) counted, as the figures break their lines
    gaps = Gaps()
    with TelemetryBlocks(path / "telemetry.csv", columns=("t",)) as tel:
        for block in tel:
            gaps.add(block[:, 0])
    events, bad_events = count_events(path / "events.jsonl")
    print(f"run {path}: {tel.rows} telemetry rows, {events} events")
    if tel.dropped_lines or bad_events or gaps.count:
        print(
            f"  unreadable: {tel.dropped_lines} telemetry lines (damaged or out of time order), "
            f"{bad_events} event lines (dropped); {gaps.count} time gaps (no row for more than "
            f"{gaps.jump:g} steps: drawn as breaks)"
        )
    if beyond := not_units(tel.header):
        print(
            f"  {beyond} per-unit columns of a unit no board has (a board has at most {MAX_UNITS}): not drawn"
        )
    damaged: dict[str, str] = {}
    if not tel.rows and tel.dropped_lines:
        # every line there is unreadable: a damaged file, not a run that ended early (it was said "the run
        # ended before its first", exit 0, of a telemetry.csv whose every row was damaged)
        damaged["telemetry.csv"] = f"none of its {tel.dropped_lines} lines after the header is a readable row"
        print(f"  no readable telemetry rows ({damaged['telemetry.csv']}): no plots")
    try:
        summary = read_summary(path)
    except InputFormatError as exc:
        print(f"  summary.json damaged ({exc.detail}): not shown, and no plots (they read it)")
        return {}, {"summary.json": exc.detail, **damaged}, None
    damage = partial = None
    if summary is None:
        partial = f"not a whole run: no summary.json ({_no_summary_why(path)}; exit status {EXIT_PARTIAL})"
        print(f"  no summary.json ({_no_summary_why(path)}): plots from the telemetry alone")
    elif (why := _not_a_rate(summary)) is not None:
        # the one value the plots take from it (hil.plots.run): a string there was a TypeError's traceback
        print(f"  summary.json damaged ({why}): not shown, and no plots (they read it)")
        return {}, {"summary.json": why, **damaged}, None
    elif (where := _not_a_number(summary)) is not None:
        # NaN and Infinity are JSON to Python, and a run writes neither (a figure it has not: null)
        damage = f"a value is not what a run writes: {where}"
        print(f"  summary.json damaged ({damage}): not shown")
    else:
        try:
            text, unreadable = checked_summary(summary)
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
            # a summary.json hil did not write: its values are not the shapes a run's summary has
            damage = f"a value is not what a run writes: {type(exc).__name__}: {exc}"
            print(f"  summary.json damaged ({damage}): not shown")
        else:  # printed outside: a terminal that cannot show a character is no damage of the file's
            print(text)
            if unreadable:  # its last line names them; the other figures are shown
                damage = f"values no run writes, shown as {UNREADABLE}: {'; '.join(unreadable)}"
    if damage is not None:
        damaged = {"summary.json": damage, **damaged}
    if not tel.rows:
        # a run that ended before its first row (its port could not be opened): nothing to draw, and not
        # an error of the report's — plot_run's "no telemetry rows to plot" once ended the command here
        if "telemetry.csv" not in damaged:
            print("  no telemetry rows (the run ended before its first): no plots")
        return {}, damaged, partial
    return (plot_run(path, processes=available_cores()) if plots else {}), damaged, partial


def _no_summary_why(path: Path) -> str:
    """Why the run directory ``path`` has no summary.json, told by its writer's lock
    (:mod:`hil.files.writing`: a run holds it from its directory's making to its summary.json, the OS lets
    go of it when the process ends however it ends). A run still running was said "killed": a report of a
    live run's rows so far, its last ones minutes old, read as the whole of a run that had died."""
    from hil.files.writing import writer_holds

    holds = writer_holds(path)
    if holds:
        return "the run is still being written: its rows so far"
    if holds is None:  # a file system without locks
        return "the run was killed, or it is still being written: this file system cannot tell"
    return "the run was killed"


def _not_a_rate(summary: dict) -> str | None:  # type: ignore[type-arg]
    """What is wrong with the summary's ``max_gimbal_rate_limit`` — the gimbal-rate plot's limit line,
    read by :func:`hil.plots.run.plot_run` — or None when it is absent, null, or a number (a run writes a
    number); a NaN or infinity is :func:`_not_a_number`'s to name."""
    limit = summary.get("max_gimbal_rate_limit")
    if limit is None or (isinstance(limit, (int, float)) and not isinstance(limit, bool)):
        return None
    return f"max_gimbal_rate_limit is {str(limit)[:40]!r}, not a rate"


def _not_a_number(doc: object, where: str = "") -> str | None:
    """``KEY is VALUE`` for the first NaN or infinity in a JSON document (keys dotted, list items by
    index), or None when every number in it is finite."""
    if isinstance(doc, float) and not math.isfinite(doc):
        return f"{where or 'the document'} is {doc}"
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        found = _not_a_number(value, f"{where}.{key}" if where else str(key))
        if found is not None:
            return found
    return None


def _campaign(path: Path, plots: bool) -> Reported:
    """Print the campaign ``path``'s summary and, with ``plots``, draw its plots and write its summary.json
    again — under the directory's lock (:func:`~hil.montecarlo.store.holding_dir`), from the runs on disk
    then. Written without it, a summary of the runs so far beside a session still appending could be the
    one left standing, describing fewer runs than runs.csv holds; a session holding the directory keeps
    its files, said."""
    from hil.montecarlo.campaign import summarise_dir, write_campaign_summary
    from hil.montecarlo.plots import plot_campaign
    from hil.montecarlo.store import MANIFEST, holding_dir, read_manifest
    from hil.montecarlo.summary import format_table
    from hil.scenario import parse_scenario
    from protocol.errors import InputFormatError

    info = read_manifest(path)
    if not isinstance(info.get("scenario_toml"), str):
        raise InputFormatError("campaign.json holds no scenario", str(path / MANIFEST))
    scenario = parse_scenario(info["scenario_toml"], path / MANIFEST)
    drawn = Reported()
    with ExitStack() as held:
        # None: the directory's lock not taken (--no-plots; or a session's, which writes its own files)
        locked = held.enter_context(holding_dir(path)) if plots else None
        # summarised in memory: --no-plots writes nothing (a read-only campaign is reported); drawing, the
        # summary.json is written again with the figures, its interrupted record carried over
        summary = summarise_dir(path, scenario, write=False, locked_here=bool(locked))
        print(f"campaign {path}: scenario {scenario.name}, seed {info.get('seed')}")
        print(format_table(summary))  # a partial campaign said there (PARTIAL: N of the M runs asked)
        drawn.partial = _not_whole(summary)
        if locked is None:
            if plots:
                print(f"  {_held_by(path)}")
            return drawn
        drawn.update(plot_campaign(path, scenario.settle_deg, scenario.spacecraft.limits.max_gimbal_rate))
        interrupted = summary.get("interrupted")
        if isinstance(interrupted, dict):
            interrupted["plots"] = "drawn for these runs by hil report"
        write_campaign_summary(path, summary)
    return drawn


def _held_by(path: Path) -> str:
    """Why the campaign ``path``'s summary.json and plots are not drawn here: who holds its lock
    (:func:`~hil.montecarlo.store.lock_holder`). Said "a session is writing this campaign" whoever held it,
    a second ``hil report`` drawing it told of a session that was not there."""
    from hil.montecarlo.store import lock_holder

    holder = lock_holder(path)
    if holder is None:
        return (
            "another process holds this campaign (a session writing it, or hil report drawing it: it did "
            "not say which): summary.json, plots left to it"
        )
    if holder.is_session:
        return (
            f"a session is writing this campaign ({holder.by}, pid {holder.pid}): its runs so far; "
            "summary.json, plots left to it"
        )
    return f"{holder.doing()}: summary.json, plots left to it"


def _not_whole(summary: dict) -> str | None:  # type: ignore[type-arg]
    """Why a campaign's summary is not a whole campaign's (its ``interrupted`` record: fewer of the runs
    asked on disk than were asked), or None."""
    partial = summary.get("interrupted")
    if not isinstance(partial, dict):
        return None
    on_disk = partial.get("runs_asked_on_disk", partial.get("runs_on_disk"))
    ended = f", its last session {str(partial['ended'])[:200]}" if partial.get("ended") else ""
    return (
        f"not a whole campaign: {on_disk} runs on disk of {partial.get('runs_asked')} asked{ended} "
        f"(exit status {EXIT_PARTIAL})"
    )
