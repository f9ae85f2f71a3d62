"""``hil replay``: run a recorded phone log through the merge and an estimator (the paper's, pre-filtered,
unless ``--estimator`` names another), and optionally drive a board with the controller's output
(``--port``)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hil.cli._parser import given_path
from hil.files.output import fit_name

if TYPE_CHECKING:
    from hil.estimation.registry import EstimatorChoice
    from hil.estimation.sensors import SensorLog
    from hil.runtime.loop import RunResult

ORDER = 30
MAX_GAP_S = 1.0  # hil.estimation.sensors.MAX_PAUSE_S (not imported here: the CLI loads its modules lazily)

EPILOG = """\
examples:
  hil replay ../shared/data/sensorlogger-android              # Sensor Logger export folder (or its .zip)
  hil replay trial.mat --out runs/broad01                      # BROAD trial: also scores against its truth
  hil replay ../shared/data/tyrex-nexus5/Guillaume_Nexus5_NoDist_Texting --preset paper
  hil replay log.csv --window 10 70 --no-plots                 # the project's own CSV, 60 s of it
  hil replay phyphox.zip --lat 52.52 --lon 13.40 --date 2019-06-01   # true north from IGRF-14 (1900-2030)
  hil replay phyphox-exports/                                  # several single-sensor phyphox exports
  hil replay log.csv --paced                                   # in real time, on the log's clock
  hil replay ../shared/data/sensorlogger-android --estimator vqf   # VQF instead (pip install vqf)

  # drive a board: the controller holds the attitude estimated after the warm-up against the log's
  # motion, its commands go to the board in real time; a run directory as `hil run` writes
  hil replay ../shared/data/sensorlogger-android --port /tmp/vscmg          # firmware-sim on a pty
  hil replay trial.mat --port /dev/ttyACM0 --scenario paper-testbed        # a real board, 3 units
  hil replay log.csv --port "emu://?units=4"                               # in-process board, lockstep

writes OUT (default runs/replay-<log name>/) estimates.csv (t_s, quaternion body->ENU, rate estimate,
flags), summary.json and figures:
attitude_error.png and rate_error.png (the paper's two) when the log has ground truth, attitude.png and
rates.png always. formats: csv, sensorlogger, sensorlogger-json, phyphox, tyrex, broad (detected when not
given).
a log without a magnetometer replays 6-axis: inclination from gravity, heading unobserved (drifts).
where the log's clock jumps by more than --max-gap seconds the filter restarts (reported).
with --port: a run directory under --out (default runs/): telemetry.csv, events.jsonl, summary.json,
plots/ (`hil report` redraws them); --paced, --progress and the estimates CSV do not apply. The log
(after --window, or its longest part; up to where its clock goes back, a restarted recording; up to where
its gyroscope or accelerometer ends) must outlast the scenario's warm-up and the rotors' settling; one
that ends before the slew started (a pause restarted the warm-up) ends "incomplete"; exit status as hil
run's (docs/faults.md).
"""

FORMATS = ("csv", "sensorlogger", "sensorlogger-json", "phyphox", "tyrex", "broad")
"""``--format``'s choices: the readers' names (:data:`hil.logs.READERS`, which a test holds them to;
spelt here so that building the command line imports no reader)."""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "replay",
        help="replay a recorded phone log through the estimator (--port: and drive a board with it)",
        description="Merge a phone log's sensors at the fastest rate, pre-filter, run the paper's "
        "variational attitude estimator, and write the estimates, a summary and figures.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("log", type=Path, help="log file or folder (see formats below)")
    p.add_argument("--format", choices=FORMATS, help="skip detection")
    p.add_argument("--out", type=given_path, help="output folder (default: runs/replay-<log name>)")
    p.add_argument(
        "--estimator",
        metavar="NAME",
        help="variational (the default), vqf (pip install vqf), or an installed package's estimator",
    )
    p.add_argument(
        "--preset",
        choices=("tuned", "paper"),
        help="the variational estimator's: tuned (default) or exactly the paper's",
    )
    p.add_argument("--window", nargs=2, type=float, metavar=("T0", "T1"), help="replay only this part (s)")
    p.add_argument(
        "--max-gap",
        type=float,
        default=MAX_GAP_S,
        metavar="S",
        help=f"restart the filter where the log's clock jumps by more (default {MAX_GAP_S:g} s)",
    )
    field = p.add_mutually_exclusive_group()
    field.add_argument(
        "--inclination", type=float, metavar="DEG", help="field inclination (default: measured)"
    )
    p.add_argument(
        "--declination",
        type=float,
        default=None,  # None: not given (0, magnetic north), so refused beside --lat/--lon/--date
        metavar="DEG",
        help="east of true north (default 0; not with --lat/--lon/--date, whose field model gives it)",
    )
    field.add_argument("--lat", type=float, help="latitude (deg) for IGRF-14 (with --lon and --date)")
    p.add_argument("--lon", type=float, help="longitude (deg) for IGRF-14")
    p.add_argument("--date", help="recording date YYYY-MM-DD for IGRF-14 (1900-2030)")
    p.add_argument(
        "--gyro-bias",
        choices=("still", "none"),
        default="still",
        help="the online bias estimate starts from the still window's mean gyro (still) or zero (none)",
    )
    p.add_argument("--paced", action="store_true", help="release steps at the log's pace (wall clock)")
    p.add_argument("--no-plots", action="store_true", help="write the CSV and summary only")
    p.add_argument("--progress", action="store_true", help="progress bar even when stderr is not a terminal")
    board = p.add_argument_group("driving a board")
    board.add_argument("--port", metavar="URL", help="drive the board at URL (a hil run transport URL)")
    board.add_argument(
        "--scenario",
        default=None,  # None: not given, so refused without --port rather than ignored
        metavar="NAME|FILE",
        help="with --port: the spacecraft, array and controller (default cubesat-1u)",
    )
    board.add_argument(
        "--lockstep", action="store_true", help="with --port emu://...: simulated time (the default there)"
    )
    p.set_defaults(func=run)


class ProgressBar:
    """A one-line progress bar on stderr: ``[####....] 45% 320000/720000 steps 3.1 s``."""

    def __init__(self, stream=sys.stderr, width: int = 30) -> None:  # type: ignore[no-untyped-def]
        self.stream = stream
        self.width = width
        self.start = time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        frac = done / total if total else 1.0
        bar = "#" * int(frac * self.width)
        elapsed = time.monotonic() - self.start
        self.stream.write(f"\r[{bar:<{self.width}}] {frac:4.0%} {done}/{total} steps {elapsed:.1f} s")
        if done >= total:
            self.stream.write("\n")
        self.stream.flush()


ANGLE_BOUNDS = {"inclination": 90.0, "declination": 180.0, "lat": 90.0, "lon": 180.0}
"""The most each angle option may be, either way (degrees)."""


def check_numbers(args: argparse.Namespace) -> None:
    """The numbers on the command line within their bounds — ``--window T0 T1`` finite with T0 < T1,
    ``--max-gap`` finite and positive, the angles within :data:`ANGLE_BOUNDS` — or one ConfigError
    naming the option."""
    from protocol.errors import ConfigError

    if args.window is not None:
        t0, t1 = args.window
        if not (math.isfinite(t0) and math.isfinite(t1) and t0 < t1):
            raise ConfigError(f"must be two finite times T0 < T1 (s), got {t0!r} {t1!r}", "--window")
    if not (math.isfinite(args.max_gap) and args.max_gap > 0):
        raise ConfigError(f"must be a finite number of seconds > 0, got {args.max_gap!r}", "--max-gap")
    for name, most in ANGLE_BOUNDS.items():
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and abs(value) <= most):
            raise ConfigError(f"must be within ±{most:g} deg, got {value!r}", f"--{name}")


def declination_of(args: argparse.Namespace) -> float:
    """``--declination`` (degrees east of true north), 0 (magnetic north) when not given."""
    return 0.0 if args.declination is None else float(args.declination)


def estimator_of(args: argparse.Namespace) -> EstimatorChoice:
    """``--estimator`` and ``--preset`` as an estimator choice: the variational estimator's tuned preset
    unless told; ``--preset`` only with the variational estimator (ConfigError naming the option)."""
    from hil.estimation.registry import DEFAULT_ESTIMATOR, EstimatorChoice
    from hil.logs.replay import REPLAY_ESTIMATOR
    from protocol.errors import ConfigError

    name = (args.estimator or DEFAULT_ESTIMATOR).lower()
    if name != "variational":
        if args.preset is not None:
            raise ConfigError(f"is the variational estimator's, not {name!r}'s", "--preset")
        return EstimatorChoice.by_name(name, "--estimator")
    if args.preset is None:
        return REPLAY_ESTIMATOR
    return EstimatorChoice(name, {"preset": args.preset}, "--preset")


def run(args: argparse.Namespace) -> int:
    from datetime import date

    from hil.estimation.inertial import decimal_year
    from hil.logs.replay import FieldModel, ReplayOptions, replay, seconds
    from hil.plots.estimator import plot_replay
    from hil.timing.clock import WallClock
    from protocol.errors import ConfigError

    check_numbers(args)
    field_model = None
    if args.lat is not None or args.lon is not None or args.date is not None:
        if args.lat is None or args.lon is None or args.date is None:
            raise ConfigError("--lat, --lon and --date go together", "hil replay")
        try:
            when = date.fromisoformat(args.date)
        except ValueError:
            raise ConfigError(f"not a YYYY-MM-DD date: {args.date!r}", "--date") from None
        field_model = FieldModel(args.lat, args.lon, decimal_year(when))
        if args.declination is not None:  # taken, then ignored: the model's declination turned the estimates
            raise ConfigError(
                "the field model of --lat/--lon/--date gives the declination: leave out one or the other",
                "--declination",
            )
    name = args.log.resolve().name.removesuffix(".zip")
    if args.port is not None:
        return _drive(args, name, field_model)
    for given, option in ((args.scenario is not None, "--scenario"), (args.lockstep, "--lockstep")):
        if given:  # taken, then ignored: a scenario file that did not exist replayed, status 0
            raise ConfigError(
                "with --port only: without one the log runs through the estimator alone, no board and no "
                'scenario (a board driven by the log: --port URL, e.g. --port "emu://?units=4")',
                option,
            )
    out = args.out or Path("runs") / fit_name(f"replay-{name}")  # a log's name of 249+ bytes: too long
    show = args.progress or sys.stderr.isatty()
    options = ReplayOptions(
        out_dir=out,
        format=args.format,
        estimator=estimator_of(args),
        inclination_deg=args.inclination,
        declination_deg=declination_of(args),
        field_model=field_model,
        gyro_bias=args.gyro_bias,
        window_s=tuple(args.window) if args.window else None,
        max_gap_s=args.max_gap,
        plotter=None if args.no_plots else plot_replay,
        paced=args.paced,
        clock=WallClock() if args.paced else None,
        progress=ProgressBar() if show else None,
    )
    result = replay(args.log, options)
    log, stats = result.log, result.merge_stats
    print(f"{log.source} ({log.format}): {result.samples_read} samples, {len(result.estimates)} steps")
    for line in result.setup:
        print(f"  {line}")
    driver = stats.driver.label if stats.driver is not None else "-"
    drops = f"nan {sum(stats.nan.values())}, duplicate {sum(stats.duplicate.values())}"
    drops += f", out of order {sum(stats.out_of_order.values())}"
    beyond = sum(result.out_of_range.values())
    if beyond:
        drops += f", beyond the sensor's range {beyond}"
    skipped = sum(result.skipped_parts.values())
    if skipped:
        drops += f", in parts not replayed {skipped}"
    print(
        f"  merge: driver {driver}, {stats.dropped + beyond + skipped} samples dropped ({drops}), "
        f"{stats.gaps} gaps, "
        f"{stats.failover_steps} failover steps"
    )
    rejected = result.mag_rejections
    if rejected:
        total = sum(b - a for a, b in rejected)
        longest = max(rejected, key=lambda ab: ab[1] - ab[0])
        print(
            f"  magnetometer left out as disturbed: {len(rejected)} intervals, {total:.1f} s in all "
            f"(longest {longest[0]:.1f}-{longest[1]:.1f} s); every interval in summary.json"
        )
    if result.gyro_bias is not None:
        print(f"  gyro bias estimate at the end: {[round(x, 5) for x in result.gyro_bias]} rad/s")
    if result.log.six_axis:
        print("  heading: NOT observed (no magnetometer): the gyroscope's integral, drifting")
    for warning in result.warnings:
        print(f"  warning: {warning}")
    if len(result.segments) > 1:
        for seg in result.segments:
            what = seg.get("skipped", f"{seg.get('steps', 0)} steps")
            print(f"  part {seconds(float(seg['t0_s']))}-{seconds(float(seg['t1_s']))} s: {what}")
    if result.comparison is not None:
        c = result.comparison
        if c.rmse.n == 0:
            print("  vs ground truth: nothing scored (no estimate where the truth is evaluated: see above)")
        else:
            print(f"  vs ground truth: RMSE {c.rmse} over {c.rmse.n} samples")
            print(f"  rate error RMS {c.rate_rmse:.4f} rad/s (truth rate differentiated from its attitude)")
    for name, path in result.files.items():
        print(f"  {name}: {path}")
    return 0


def _drive(args: argparse.Namespace, name: str, field_model: object) -> int:
    """``--port``: the log as the phone of a run that drives the board (hil.runtime)."""
    from hil.cli.run import LiveProgress, Plotter, report_ended
    from hil.estimation.inertial import field_warnings
    from hil.logs import read_log
    from hil.logs.rates import rate_drops
    from hil.logs.replay import (
        ReplayOptions,
        before_clock_restart,
        configure,
        drop_out_of_range,
        field_model_of,
        pinned_warnings,
        rate_drop_warning,
        silence_warnings,
        split_at_gaps,
        steerable_end,
    )
    from hil.runtime import ReplayInput, RunOptions
    from hil.runtime import run as run_scenario
    from hil.runtime.phases import ROTOR_SETTLE_S
    from hil.scenario import DEFAULT_SCENARIO, load_scenario
    from protocol.errors import ConfigError

    if args.paced:
        raise ConfigError("a board is always driven on the clock: leave out --paced", "--port")
    scenario = load_scenario(args.scenario if args.scenario is not None else DEFAULT_SCENARIO)
    log = read_log(args.log, args.format)
    if args.window:
        log = log.window(*args.window)
    log, restarted = before_clock_restart(log, args.max_gap)
    if restarted is not None:
        print(f"warning: {restarted}", file=sys.stderr)
    parts = split_at_gaps(log, args.max_gap)
    if len(parts) > 1:  # a board is driven on the clock: never wait out a gap; drive the longest part
        t0, t1 = max(parts, key=lambda p: p[1] - p[0])
        print(
            f"warning: the log's clock jumps by more than {args.max_gap:g} s {len(parts) - 1} time(s); "
            f"driving the board with its longest part, {t0:.3f}-{t1:.3f} s",
            file=sys.stderr,
        )
        log = log.window(t0, t1)
    log, cut_short = steerable_end(log)
    if cut_short is not None:
        print(f"note: {cut_short}", file=sys.stderr)
    # the warm-up, then the rotors' settling before the first slew: the shortest a log can be and still
    # reach the slew (a 2.5 s log armed and spun the rotors up, then ended "incomplete"; the spin-up's own
    # time, which depends on the rotors, comes on top)
    least_s = scenario.loop.warmup_s + ROTOR_SETTLE_S
    if not log.end - log.start > least_s:
        raise ConfigError(
            f"the log drives {log.end - log.start:.2f} s, not longer than the scenario's warm-up and the "
            f"rotors' settling ({least_s:g} s): the controller would never hold an attitude (a longer log "
            "or --window)",
            "--port",
        )
    check_steerable_rate(log)
    options = ReplayOptions(
        out_dir=Path("."),
        estimator=estimator_of(args),
        inclination_deg=args.inclination,
        declination_deg=declination_of(args),
        field_model=field_model,  # type: ignore[arg-type]
        gyro_bias=args.gyro_bias,
    )
    # the still window's means without readings beyond range; the host's admission drops and counts those
    in_range, _ = drop_out_of_range(log, options.limits)
    estimator, site, setup = configure(in_range, options)
    print(
        f"{log.source} ({log.format}): {log.n_samples} samples over {log.end - log.start:.1f} s",
        file=sys.stderr,
    )
    for line in setup:
        print(f"  {line}", file=sys.stderr)
    slowed = [rate_drop_warning(drop) for drop in rate_drops(log, args.max_gap)]
    said = [*field_warnings(log, field_model_of(options)), *slowed, *pinned_warnings(log)]
    for warning in [*said, *silence_warnings(log, options.policy.stale_after_s)]:
        print(f"  warning: {warning}", file=sys.stderr)
        setup.append(f"warning: {warning}")
    plotter = None if args.no_plots else Plotter()  # its imports overlap the run, as hil run's
    try:
        result = run_scenario(
            scenario,
            RunOptions(
                port=args.port,
                lockstep=True if args.lockstep else None,
                out_root=args.out or Path("runs"),
                progress=LiveProgress(),
                label=f"replay-{name}",
                replay=ReplayInput(log, estimator, site, tuple(setup)),
                report_late_signal=True,  # a signal as the run wrote its ending: reported, status 1
            ),
        )
    except BaseException:
        if plotter is not None:
            plotter.cancel()
        raise
    _merge_warned(result)
    return report_ended(result, plotter, "hil replay")


def check_steerable_rate(log: SensorLog) -> None:
    """Refuse (ConfigError) a log whose gyroscope or accelerometer — the two the host steers with — samples
    more than the host's stale bound (:data:`hil.runtime.faults.STALE_AFTER_S`, 0.25 s) apart at its
    median: every interval between two of its samples is then a phone gap, the host never steers, and the
    run ends "phone lost". A 2 Hz log armed the board, spun its rotors up and ended status 3 "lost: phone
    lost … (phone_gap, phone_batched)" — for a recording, not a phone, that was never fast enough."""
    from hil.estimation.sensors import SensorKind
    from hil.runtime.faults import STALE_AFTER_S
    from protocol.errors import ConfigError

    for kind, name in ((SensorKind.GYR, "gyroscope"), (SensorKind.ACC, "accelerometer")):
        period_s = log.streams[kind].median_period()
        if period_s > STALE_AFTER_S:
            raise ConfigError(
                f"the log's {name} samples every {period_s:.3g} s (median), further apart than the "
                f"{STALE_AFTER_S:g} s after which the host takes the phone for stale: it would never steer "
                "on it (a log at 4 Hz or faster; `hil replay LOG` without --port runs the estimator over it)",
                "--port",
            )


def admission_warnings(summary: Mapping[str, Any]) -> list[str]:
    """What the host's admission dropped of a recording played to a board (``summary.json``'s
    ``phone_admission``, against ``replay.samples_released``), when more than
    :data:`hil.logs.replay.LOSS_WARNED` of it, as one warning naming the reasons. The host drops a
    recording's repeated, out-of-order, out-of-range or stray samples before its merge sees them, so
    :func:`hil.logs.replay.merge_warnings` counts none of them: a log whose every row was written three
    times (two thirds of it dropped) said "completed" without a word, where the batch replay warned."""
    from hil.logs.replay import LOSS_WARNED

    admission = summary.get("phone_admission")
    replay = summary.get("replay")
    if not (isinstance(admission, dict) and isinstance(replay, dict)):
        return []
    dropped = admission.get("dropped")
    released = replay.get("samples_released")
    if not (isinstance(dropped, dict) and isinstance(released, int) and released > 0):
        return []
    counts = {reason: n for reason, n in dropped.items() if isinstance(n, int) and n > 0}
    lost = sum(counts.values())
    if not lost > LOSS_WARNED * released:
        return []
    why = ", ".join(f"{n} {reason.replace('_', ' ')}" for reason, n in counts.items())
    causes = "; ".join(ADMISSION_CAUSES.get(reason, reason) for reason in counts)
    return [
        f"the host dropped {lost} of the recording's {released} samples ({why}): {causes}; the board was "
        "steered on what is left"
    ]


ADMISSION_CAUSES = {
    "bad_time": "times that are no number",
    "non_finite": "readings that are no number",
    "out_of_range": "readings beyond a phone sensor's range",
    "future": "times far ahead of the samples after them",
    "past": "times far behind the samples before them",
    "duplicate": "a sensor's clock repeats times (or they are beyond what a float64 second resolves)",
    "out_of_order": "a sensor's rows are not in time order, or its clock is broken",
    "burst": "a sensor's samples closer than 0.1 ms, faster than any phone",
    "slow_clock": "a clock that runs slow against the run's",
}
"""What each of the admission's drop reasons (:data:`hil.estimation.admission.REASONS`) says of a log, for
:func:`admission_warnings`."""


def _merge_warned(result: RunResult) -> None:
    """The warnings the run's merge counters call for (:func:`hil.logs.replay.merge_warnings`, the batch
    replay's: a sensor silent or NaN for much of the log, rows out of order) and its admission's
    (:func:`admission_warnings`: the samples the host dropped before its merge), printed and in its
    ``summary.json`` (``replay.warnings``). A magnetometer that stopped a quarter into the log left heading
    unobserved for the rest, and the run said "completed" without a word, where the batch replay warned."""
    from hil.logs.replay import merge_stats_of, merge_warnings
    from hil.runtime.runlog import write_summary

    counts = result.summary.get("phone_merge")
    warnings = merge_warnings(merge_stats_of(counts)) if isinstance(counts, dict) else []
    warnings += admission_warnings(result.summary)
    if not warnings:
        return
    for warning in warnings:
        print(f"warning: {warning}", file=sys.stderr)
    result.summary.setdefault("replay", {})["warnings"] = warnings
    if result.run_dir is not None:
        try:
            write_summary(result.run_dir, result.summary)
        except OSError as exc:  # the run's summary.json stays as the run wrote it; the warnings are said
            print(f"hil replay: {exc}", file=sys.stderr)
