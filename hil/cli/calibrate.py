"""``hil calibrate``: fit bench CSVs into calibration files, make bench data and test vectors, inspect;
through a board (``esc``, ``sweep``, ``unit``: :mod:`hil.cli._calibrate_board`): teach ESCs their
endpoints, sweep channels into bench CSVs, calibrate units in one go."""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from hil.cli._parser import given_path
from hil.numbers import MAX_SEED

if TYPE_CHECKING:
    from hil.calibration.bench import BenchData
    from hil.calibration.files import CalibrationSet, UnitEntry
    from hil.calibration.fit import Fit

ORDER = 40

_FIT_EXAMPLES = """examples:
  # fit all three maps of unit 0 into a new file (and save cal/pyramid-unit0.png)
  hil calibrate fit bench/unit0_rotor.csv bench/unit0_gimbal_rate.csv bench/unit0_gimbal_angle.csv \\
      -o cal/pyramid.toml --unit 0 --name pyramid-a
  # refit only the rotor of unit 2 in an existing file (its gimbal maps are kept)
  hil calibrate fit today_rotor.csv -o cal/pyramid.toml --unit 2
  # an ESC calibrated to 1100..1940 µs, a coarser throttle table, a plot elsewhere
  hil calibrate fit rotor.csv -o unit.toml --base default --esc-low 1100 --esc-high 1940 \\
      --rotor-knots 7 --plot /tmp/rotor_fit.svg
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "calibrate",
        help="calibrate a bench through its board (ESC endpoints, sweeps, fit, upload, verify); fit CSVs",
        description="Calibration maps: through a board, teach ESCs their endpoints, sweep channels into "
        "bench CSVs, or calibrate units in one go (sweep, fit, upload, read back, verify, save); offline, "
        "fit bench CSVs into a calibration file, generate bench data from the stated motor models, write "
        "test vectors for other implementations, show a file.",
        epilog="Run 'hil calibrate ACTION --help' for each action's options and examples.",
    )
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")

    f = actions.add_parser(
        "fit",
        help="fit bench CSVs, write the calibration file, save a plot, print residuals",
        description="Fit each bench CSV (its measurement column says which map: rpm or rotor_speed_rad_s, "
        "gimbal_rate_*, gimbal_angle_*) and store the maps as unit N of the output file. Maps without a CSV "
        "are kept from the unit already in the output file, or taken from --base.",
        epilog=_FIT_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    f.add_argument("csv", nargs="+", type=Path, help="bench CSV files (at most one per map)")
    f.add_argument(
        "-o", "--out", type=given_path, required=True, help="calibration file to write or update (TOML)"
    )
    f.add_argument("--unit", type=int, default=0, help="unit index in the file, 0..7 (default 0)")
    f.add_argument("--name", help="unit label (default: kept, or unitN)")
    f.add_argument("--base", help="where maps without a CSV come from: a calibration file, or 'default'")
    f.add_argument("--plot", type=Path, help="image of data against fit (default: OUT's stem + -unitN.png)")
    f.add_argument("--esc-low", type=float, default=1000.0, help="ESC's calibrated low endpoint, µs (1000)")
    f.add_argument("--esc-high", type=float, default=2000.0, help="ESC's calibrated high endpoint, µs (2000)")
    f.add_argument("--rotor-knots", type=int, default=9, help="knots of the throttle curve, 3..16 (9)")
    f.add_argument("--gimbal-rate-knots", type=int, default=6, help="knots each side of the dead zone (6)")
    f.add_argument("--gimbal-angle-knots", type=int, default=9, help="knots of the angle table (9)")
    f.add_argument(
        "--allow-partial",
        action="store_true",
        help="fit a bench CSV marked '# status: partial' (a sweep cut short) anyway, with a warning",
    )
    f.set_defaults(func=run_fit)

    b = actions.add_parser(
        "bench",
        help="write seeded bench CSVs generated from the stated motor and servo models",
        description="Synthetic bench data (unit-to-unit spread and measurement noise on the stated models, "
        "docs/calibration.md): unit<i>_rotor.csv, unit<i>_gimbal_rate.csv, unit<i>_gimbal_angle.csv.",
        epilog="examples:\n  hil calibrate bench --out-dir fixtures/calibration/bench --units 4 --seed 1\n"
        "  hil calibrate bench --out-dir /tmp/bench --units 3 --seed 7 --mirrored 0 2",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    b.add_argument("--out-dir", type=given_path, required=True, help="directory for the CSV files")
    b.add_argument("--units", type=int, default=4, help="number of units (4)")
    b.add_argument("--seed", type=int, default=1, help="random seed (1)")
    b.add_argument(
        "--mirrored",
        type=int,
        nargs="*",
        help="units with mirrored gimbals (default: unit 3, if there is one)",
    )
    b.set_defaults(func=run_bench)

    s = actions.add_parser(
        "show",
        help="check a calibration file and print each unit's maps and binary size",
        description="Load and validate a calibration file; print each unit's maps, fit residuals and the "
        "size and CRC of its binary set (what a CALIBRATION transfer carries).",
        epilog="examples:\n  hil calibrate show fixtures/calibration/pyramid4.toml\n"
        "  hil calibrate show unit.toml --hex",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    s.add_argument("file", type=Path, help="calibration file (TOML)")
    s.add_argument("--hex", action="store_true", help="also print each unit's binary set in hex")
    s.set_defaults(func=run_show)

    v = actions.add_parser(
        "vectors",
        help="write test vectors of the binary format and the maps (for the C firmware's tests)",
        description="Binary sets, conversions with their expected results and malformed sets with the "
        "field they break, as JSON, from the default unit and the units of a calibration file.",
        epilog="example:\n  hil calibrate vectors fixtures/calibration/pyramid4.toml "
        "-o fixtures/calibration/vectors.json",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    v.add_argument("file", type=Path, help="calibration file whose units to include")
    v.add_argument("-o", "--out", type=given_path, required=True, help="JSON file to write")
    v.set_defaults(func=run_vectors)

    from ._calibrate_board import register_actions

    register_actions(actions)


# --------------------------------------------------------------------------- fit
def run_fit(args: argparse.Namespace) -> int:
    from hil.calibration.bench import read_bench_csv
    from hil.calibration.files import CalibrationSet, load_calibration, relative_source, save_calibration
    from hil.calibration.fit import FitOptions, fit_bench
    from hil.calibration.plot import plot_fits
    from hil.calibration.plot import plot_path as default_plot_path
    from hil.calibration.textfiles import (
        check_distinct,
        check_text,
        check_writable,
        locked,
        shown,
    )
    from protocol.errors import CalibrationError, ConfigError
    from protocol.messages import MAX_UNITS

    from ._calibrate_board import say

    # refused before anything is read or fitted, naming the option: the file's own check (a unit entry's,
    # whose words these are) came only after every fit was done
    if not 0 <= args.unit < MAX_UNITS:
        raise ConfigError(f"unit index: {args.unit} is not a unit number 0..{MAX_UNITS - 1}", "--unit")
    options = FitOptions(
        esc_low_us=args.esc_low,
        esc_high_us=args.esc_high,
        rotor_knots=args.rotor_knots,
        gimbal_rate_knots_per_side=args.gimbal_rate_knots,
        gimbal_angle_knots=args.gimbal_angle_knots,
    )
    check_writable(args.out, f"-o {args.out}")  # a FIFO read as the file to update waited for ever
    plot_path = _plot_target(args.plot, default_plot_path(args.out, args.unit))  # before anything is written
    plot_option = f"--plot {plot_path}" if args.plot is not None else f"the plot {plot_path}"
    check_distinct(
        {f"-o {args.out}": args.out, plot_option: plot_path}, {f"the CSV {p}": p for p in args.csv}
    )
    if args.name is not None:  # the file stores them: refused before the fits, not by the file's write
        check_text(args.name, "--name", ConfigError)
    for path in args.csv:
        relative_source(path, args.out, f"the CSV {shown(str(path))}")
    # --base FILE read before the fits too: one without the unit (or not a calibration file) was refused
    # only after every CSV was fitted
    base_set = load_calibration(args.base) if args.base and args.base != "default" else None
    if base_set is not None and base_set.unit(args.unit) is None:
        raise CalibrationError(f"has no unit {args.unit}", args.base)
    datasets = [read_bench_csv(path) for path in args.csv]
    for d in datasets:
        if d.partial is not None and not args.allow_partial:
            raise CalibrationError(
                f"a partial sweep ({d.partial}): it may not cover the range a fit needs; sweep again, or "
                "fit it anyway with --allow-partial",
                d.path,
            )
        if d.partial is not None:
            print(f"warning: fitting a partial sweep: {d.partial}", file=sys.stderr, flush=True)
    kinds = [d.kind.value for d in datasets]
    for d in datasets:
        if kinds.count(d.kind.value) > 1:
            raise CalibrationError(
                f"one of {kinds.count(d.kind.value)} {d.kind.value} CSVs; give one per map", d.path
            )
    fits = [(d, fit_bench(d, options)) for d in datasets]
    # Load, merge, plot and save under one lock on the file: two fits into one file at once each read it
    # and wrote it back with their own unit only (one unit lost). The plot is saved before the file: a plot
    # that cannot be saved ends the command with the file unchanged (it was written, then the command said
    # only "error: cannot save the plot"), and a plot without its file is only a picture of the fit.
    with locked(args.out, f"-o {args.out}"):
        existing = load_calibration(args.out) if args.out.exists() else CalibrationSet(())
        entry, kept, base_label = _fitted_unit(args, existing, base_set, fits)
        try:
            plot_path = plot_fits(fits, plot_path, title=f"{args.out.name}: unit {args.unit} ({entry.name})")
        except ConfigError as exc:
            raise ConfigError(f"{exc.detail}; {args.out} was not written", exc.where) from exc
        written = save_calibration(existing.with_unit(entry), args.out)
    for _, fit in fits:
        say(fit.report.summary())
    if kept:
        say(f"kept from {base_label}: {', '.join(kept)}")
    size = len(entry.calibration.to_bytes())
    say(f"wrote {written} (unit {args.unit}, {size}-byte binary set), plot {plot_path}")
    return 0


def _fitted_unit(
    args: argparse.Namespace,
    existing: CalibrationSet,
    base_set: CalibrationSet | None,
    fits: list[tuple[BenchData, Fit]],
) -> tuple[UnitEntry, list[str], str]:
    """``hil calibrate fit``'s unit: the fitted maps, the others (and their provenance) from the unit
    already in ``existing`` (the output file, read under its lock) or from ``--base`` (``base_set``, the
    file it names, read before the fits; None for none or 'default'); with the maps kept
    and where they came from. :class:`CalibrationError` when maps are missing and there is nowhere to take
    them from."""
    from dataclasses import replace

    from hil.calibration.files import FitInfo, UnitEntry, relative_source
    from protocol.calibration import UnitCalibration, default_unit_calibration
    from protocol.errors import CalibrationError

    out_dir = args.out.resolve().parent
    base, base_dir, base_label = existing.unit(args.unit), out_dir, str(args.out)
    if args.base == "default":
        base, base_label = (
            UnitEntry(args.unit, f"unit{args.unit}", default_unit_calibration()),
            "the default unit",
        )
    elif base_set is not None:
        base, base_dir, base_label = (
            base_set.unit(args.unit),
            Path(args.base).resolve().parent,
            args.base,
        )
    maps = {d.kind.value: fit.map for d, fit in fits}
    kept = [k for k in ("rotor", "gimbal_rate", "gimbal_angle") if k not in maps]
    if kept and base is None:
        raise CalibrationError(
            f"no data for {', '.join(kept)}: give their CSVs, or --base FILE|default to take them from",
            str(args.out),
        )
    if base is not None:
        maps = {
            k: maps.get(k, getattr(base.calibration, k)) for k in ("rotor", "gimbal_rate", "gimbal_angle")
        }
    cal = UnitCalibration(maps["rotor"], maps["gimbal_rate"], maps["gimbal_angle"])  # type: ignore[arg-type]
    provenance = {}
    for k in kept:
        info = base.fits.get(k) if base is not None else None
        if info is not None:
            provenance[k] = replace(info, source=os.path.relpath(base_dir / info.source, out_dir))
    for d, fit in fits:
        r = fit.report
        source = relative_source(d.path, args.out, f"the CSV {d.path}")
        provenance[d.kind.value] = FitInfo(source, r.points, r.rms, r.max_abs, r.unit, r.battery_v)
    name = args.name or (base.name if base is not None and args.base != "default" else f"unit{args.unit}")
    return UnitEntry(args.unit, name, cal, provenance), kept, base_label


def _plot_target(given: Path | None, default: Path) -> Path:
    """The file ``hil calibrate fit``'s plot will be saved as — ``--plot`` (``given``) or ``default``,
    beside the calibration file — checked before the calibration file is written (a plot refused after it
    left the file changed and said the command failed): a name without a suffix gets ``.png`` (what
    matplotlib saves it as, and so the path said), any other suffix must be an image format matplotlib
    writes, a folder or another file that is not a regular one (a FIFO: saving to it failed after the
    calibration file was written) is refused, and the folder a given path goes in is made (the default's
    is the calibration file's, which saving it makes or refuses). Anything else is a :class:`ConfigError`
    naming ``--plot`` and the path."""
    import hil.plots  # noqa: F401  (first: it imports matplotlib whatever MPLBACKEND says)

    # isort: split
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from protocol.errors import ConfigError

    path = given if given is not None else default
    if not path.suffix:
        path = path.with_name(f"{path.name}.png")
    where = f"--plot {path}" if given is not None else str(path)
    formats = FigureCanvasAgg.get_supported_filetypes()
    if path.suffix[1:].lower() not in formats:
        raise ConfigError(
            f"cannot save the plot as {path.suffix!r}, not an image format; give one of "
            f"{', '.join('.' + f for f in sorted(formats))}",
            where,
        )
    if path.is_dir():
        raise ConfigError("cannot save the plot: a folder, not an image file", where)
    if path.exists() and not path.is_file():
        raise ConfigError("cannot save the plot: not a regular file (a FIFO, a device or a socket)", where)
    if given is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            why = exc.strerror or exc
            raise ConfigError(f"cannot save the plot: cannot make its folder: {why}", where) from exc
    return path


# --------------------------------------------------------------------------- bench
DEFAULT_MIRRORED = (3,)
"""The units ``hil calibrate bench`` mirrors without ``--mirrored`` (those the bench has)."""


def run_bench(args: argparse.Namespace) -> int:
    from hil.calibration.generate import generate_bench
    from protocol.errors import ConfigError

    if not 1 <= args.units <= 8:
        raise ConfigError(f"{args.units} is outside 1..8", "--units")
    if not 0 <= args.seed <= MAX_SEED:  # numpy's generators take no negative seed (a ValueError traceback)
        raise ConfigError(f"must be an integer in 0..{MAX_SEED}, got {args.seed}", "--seed")
    if args.mirrored is None:
        mirrored = [unit for unit in DEFAULT_MIRRORED if unit < args.units]
    else:
        mirrored = args.mirrored
    for unit in mirrored:  # a unit the bench does not have was ignored, unsaid
        if not 0 <= unit < args.units:
            raise ConfigError(
                f"unit {unit} is not one of the bench's units 0..{args.units - 1}", "--mirrored"
            )
    paths = generate_bench(args.out_dir, args.units, args.seed, tuple(mirrored))
    _say(f"wrote {len(paths)} bench CSVs to {args.out_dir} (seed {args.seed})")
    return 0


# --------------------------------------------------------------------------- show
def run_show(args: argparse.Namespace) -> int:
    from hil.calibration.files import load_calibration
    from protocol.crc import crc16_ccitt_false

    cset = load_calibration(args.file)
    for u in cset.units:
        c = u.calibration
        esc, rate = c.rotor.esc, c.gimbal_rate
        data = c.to_bytes()
        lo, hi = rate.rate_range
        _say(f"unit {u.index} ({u.name}): binary set {len(data)} bytes, CRC {crc16_ccitt_false(data):#06x}")
        _say(
            f"  rotor: ESC {esc.low_us:g}-{esc.high_us:g} µs, deadband {esc.deadband_us:.1f} µs, "
            f"KV {c.rotor.kv_rad_s_per_v:.3f} rad/s/V ({c.rotor.kv_rad_s_per_v * 30 / math.pi:.0f} rpm/V), "
            f"{len(c.rotor.curve.x)} knots"
        )
        _say(
            f"  gimbal rate: {lo:.3f}..{hi:.3f} rad/s, dead zone {rate.dead_zone_us[0]:.1f}-"
            f"{rate.dead_zone_us[1]:.1f} µs, hold {rate.hold_us:.1f} µs"
        )
        a = c.gimbal_angle.curve
        _say(f"  gimbal angle: {min(a.y):.3f}..{max(a.y):.3f} rad over {a.x[0]:g}-{a.x[-1]:g} µs")
        for name, fit in u.fits.items():
            _say(
                f"  fit {name}: {fit.source}, {fit.points} points, rms {fit.rms_residual:.4g} "
                f"{fit.residual_unit}, max {fit.max_residual:.4g}"
            )
        if args.hex:
            _say("  " + data.hex())
    return 0


# --------------------------------------------------------------------------- vectors
def run_vectors(args: argparse.Namespace) -> int:
    from hil.calibration.files import load_calibration
    from hil.calibration.vectors import write_vectors

    cset = load_calibration(args.file)
    out = write_vectors(
        cset, args.out, source=os.path.relpath(args.file.resolve(), args.out.resolve().parent)
    )
    _say(f"wrote {out}")
    return 0


def _say(line: str) -> None:
    """A line on stdout; a closed one ends the output, not the command (``show | head -1``)."""
    from ._calibrate_board import say

    say(line)
