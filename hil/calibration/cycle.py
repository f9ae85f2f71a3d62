"""One go at a board: (teach the ESCs,) sweep, fit, upload, read back, verify, save — ``hil calibrate unit``.

:func:`calibrate_units` does, for the units given (swept together):

1. read each unit's present set back from the board (the base for maps not swept, and what is put back
   if verification fails);
2. optionally teach each rotor ESC its endpoints (:func:`~hil.calibration.esc.program_esc`);
3. sweep each map asked for (:func:`~hil.calibration.sweep.run_sweep`) and write its bench CSV
   (``<bench_dir>/unit<N>_<map>.csv``); a sweep stopped by a guard ends the run here;
4. fit every CSV (:func:`~hil.calibration.fit.fit_bench`, with the ESC endpoints taught); **a fit that
   fails validation ends the run before anything is uploaded**; each unit's fits are drawn beside the
   calibration file (``<out stem>-unit<N>.png``, as ``hil calibrate fit`` does);
5. upload each unit's new set (``CALIBRATION`` transfer), download it again and require the same bytes;
6. run the verification sweep (:func:`~hil.calibration.verify.run_verify`) through the uploaded maps —
   every map the upload changes: the swept ones, and a map kept from the file that is not the one the
   board held (:func:`maps_to_verify`; it used to verify the swept maps only, so a file's map was uploaded
   unchecked); if any point misses its tolerance the previous sets are uploaded back and the run fails.
   An upload or a verification that does not finish (the board lost, reset or stalled; an interrupt) puts
   the previous sets back too, wherever the board can still be reached, reads them back, and says what the
   board holds: a set half sent, or whole but unverified, is never left looking done;
7. save the units into the array's calibration file (created or updated; other units kept), with each
   fitted map's provenance (CSV, points, residuals). The save is guarded as the upload is: a run that
   ends before the file holds the new sets (interrupted, the file unwritable or hand-edited meanwhile)
   puts the previous sets back, so the board never keeps a set no file records.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path

from hil.runtime.held_signals import deferred
from protocol.calibration import UnitCalibration
from protocol.errors import CalibrationError, ConfigError, HilError, LinkError

from .bench import BenchKind, read_bench_csv
from .benchlink import BenchLink, GuardTripped
from .esc import EscOutcome, EscProgram, program_esc
from .files import (
    CalibrationSet,
    FitInfo,
    UnitEntry,
    load_calibration,
    relative_source,
    save_calibration,
)
from .fit import Fit, FitOptions, fit_bench
from .operator import Operator
from .plot import plot_fits, plot_path
from .progress import Report, no_report
from .sweep import SweepPlan, SweepResult, not_written, run_sweep
from .textfiles import check_distinct, check_writable, locked
from .verify import VerifyPlan, VerifyReport, run_verify


@dataclass(frozen=True)
class CycleOptions:
    """What :func:`calibrate_units` does. ``plans``: one sweep per map to calibrate (the others are kept
    from the file, else from the board); ``esc``: teach the ESCs first (None: they already know
    ``fit.esc_low_us``..``fit.esc_high_us``); ``verify`` None skips verification."""

    out: Path
    bench_dir: Path
    plans: tuple[SweepPlan, ...] = field(default_factory=lambda: tuple(SweepPlan(k) for k in BenchKind))
    fit: FitOptions = field(default_factory=FitOptions)
    esc: EscProgram | None = None
    verify: VerifyPlan | None = field(default_factory=VerifyPlan)


@dataclass(frozen=True)
class CycleResult:
    """What a successful run did: per unit its fits, the sweeps, the ESC outcomes, the verification, the
    fit plots."""

    calibrations: dict[int, UnitCalibration]
    fits: dict[int, dict[BenchKind, Fit]]
    sweeps: dict[int, dict[BenchKind, SweepResult]]
    csvs: dict[int, dict[BenchKind, Path]]
    esc: dict[int, EscOutcome]
    verify: VerifyReport | None
    saved: Path
    plots: dict[int, Path] = field(default_factory=dict)


def calibrate_units(
    link: BenchLink,
    units: list[int],
    options: CycleOptions,
    *,
    confirm_unloaded: bool = False,
    operator: Operator | None = None,
    report: Report = no_report,
) -> CycleResult:
    """See the module docstring. ``operator`` is asked for the ESC supply on a board without a supply
    switch (:func:`~hil.calibration.esc.program_esc`); ``report`` gets one line per step, with the time
    left (the CLI prints them).

    Everything that can be refused without the board is checked before it is driven (:func:`check_cycle`)."""
    existing = check_cycle(units, options)
    for unit in units:
        link.check_unit(unit)
    kinds = [p.kind for p in options.plans]
    client = link.client
    previous = {u: client.download_calibration(u) for u in units}
    fit_options = options.fit
    esc: dict[int, EscOutcome] = {}
    if options.esc is not None:
        fit_options = FitOptions(
            esc_low_us=options.esc.low_us,
            esc_high_us=options.esc.high_us,
            rotor_knots=options.fit.rotor_knots,
            gimbal_rate_knots_per_side=options.fit.gimbal_rate_knots_per_side,
            gimbal_angle_knots=options.fit.gimbal_angle_knots,
        )
        for unit in units:
            esc[unit] = program_esc(
                link,
                unit,
                options.esc,
                confirm_unloaded=confirm_unloaded,
                operator=operator,
                report=report,
            )
            report(f"unit {unit}: ESC taught {options.esc.low_us}-{options.esc.high_us} us")
    sweeps: dict[int, dict[BenchKind, SweepResult]] = {u: {} for u in units}
    csvs: dict[int, dict[BenchKind, Path]] = {u: {} for u in units}
    for n, plan in enumerate(options.plans, start=1):
        paths = {u: options.bench_dir / f"unit{u}_{plan.kind.value}.csv" for u in units}
        report(f"sweep {n} of {len(options.plans)}: {plan.kind.value}, {len(plan.pulses())} steps")
        results = run_sweep(link, units, plan, paths=paths, report=report)
        for unit, result in results.items():
            sweeps[unit][plan.kind], csvs[unit][plan.kind] = result, paths[unit]
            if result.rows:
                report(f"unit {unit}: {plan.kind.value} sweep, {len(result.rows)} steps -> {paths[unit]}")
            else:  # stopped before its first step (its guard): the file there is left as it was
                report(f"unit {unit}: {plan.kind.value} sweep, no step measured: {not_written(paths[unit])}")
        stopped = next((r.stopped for r in results.values() if r.stopped), None)
        if stopped:
            raise GuardTripped(f"the {plan.kind.value} sweep stopped early ({stopped}); nothing was uploaded")
    data = {u: {k: read_bench_csv(p) for k, p in csvs[u].items()} for u in units}
    fits = {u: {k: fit_bench(d, fit_options) for k, d in data[u].items()} for u in units}
    plots: dict[int, Path] = {}
    for unit in units:
        for fit in fits[unit].values():
            report(f"unit {unit}: {fit.report.summary()}")
        pairs = [(data[unit][k], fits[unit][k]) for k in fits[unit]]
        plots[unit] = plot_fits(pairs, plot_path(options.out, unit), title=f"{options.out.name}: unit {unit}")
        report(f"unit {unit}: fit plot -> {plots[unit]}")
    calibrations = {u: _assemble(fits[u], existing.unit(u), previous[u]) for u in units}
    uploaded: list[int] = []  # units whose set went out, wholly or in part
    verified = None
    saved: Path | None = None
    order = list(calibrations)
    step = f"the upload of unit {order[0]}'s set"
    try:
        for i, (unit, cal) in enumerate(calibrations.items()):
            step = f"the upload of unit {unit}'s set"
            uploaded.append(unit)
            client.upload_calibration(unit, cal)
            back = client.download_calibration(unit)
            if back.to_bytes() != cal.to_bytes():
                raise CalibrationError(
                    f"unit {unit}: the set read back differs from the one uploaded", "board"
                )
            link.check_board(step)  # a board that reset after the read-back no longer holds it
            # this unit's upload is done: what is cut short from here on is the next step
            step = f"the upload of unit {order[i + 1]}'s set" if i + 1 < len(order) else "verification"
            report(f"unit {unit}: uploaded and read back ({len(cal.to_bytes())} bytes)")
        if options.verify is not None:
            checks = {u: maps_to_verify(kinds, cal, previous[u]) for u, cal in calibrations.items()}
            for unit in calibrations:
                report(f"unit {unit}: {_verify_plan_text(kinds, checks[unit], options.out)}")
            verified = run_verify(link, calibrations, options.verify, checks, report=report)
            report(verified.table())
        if verified is None or verified.ok:
            # The save is part of the run the put-back guards: a run that ends before the file holds the
            # new sets (interrupted after its verification, the file unwritable, or hand-edited meanwhile
            # so that its re-read fails) left them on the board, recorded nowhere, and said only
            # "interrupted" or the file's error. Signals are held over the save itself (deferred): it is
            # either not begun (put back) or whole, and `saved` then says the board and the file agree.
            step = f"the save of {options.out}"
            with deferred():
                saved = _save(existing, options.out, calibrations, fits, csvs)
    except BaseException as exc:
        if saved is not None:  # an interrupt held over the save, raised after it: board and file agree
            with contextlib.suppress(Exception):
                report(f"saved units {units} in {saved} (the board holds them, verified); then interrupted")
            raise
        # A board lost, reset, stalled or interrupted mid-upload, mid-verification or before its save — or
        # anything else that ends the run there (a closed stdout's BrokenPipeError, a file that cannot be
        # written, a bug): a new set may sit on the board half sent, whole but unverified, or verified but
        # in no file. Never leave that looking done: put the previous sets back where the board can still
        # be reached, read them back, and say what it holds.
        held = _put_back(link, {u: previous[u] for u in uploaded})
        if isinstance(exc, HilError):
            raise CalibrationError(
                f"{step} did not finish ({exc}); {held}; {_not_written(plots)}", str(options.out)
            ) from exc
        with contextlib.suppress(Exception):  # the report itself may be what failed (a closed stdout)
            report(f"{step} did not finish: {held}; {_not_written(plots)}")
        raise
    if verified is not None and not verified.ok:
        held = _put_back(link, previous)
        bad = [p for p in verified.points if not p.ok]
        raise CalibrationError(
            f"{len(bad)} verification point(s) outside tolerance (e.g. {bad[0].line()}); {held}; "
            f"{_not_written(plots)}",
            str(options.out),
        )
    assert saved is not None  # verified, or not asked to be: saved in the try above
    report(f"saved units {units} in {saved}")
    return CycleResult(calibrations, fits, sweeps, csvs, esc, verified, saved, plots)


def check_cycle(units: list[int], options: CycleOptions) -> CalibrationSet:
    """What :func:`calibrate_units` refuses before the board is driven (a :class:`ConfigError` naming
    the option): a unit given twice, a map swept twice, ESCs to be taught new endpoints without a rotor
    sweep (the rotor map kept would be the one of the old endpoints, and never verified), and an output —
    the calibration file, its fit plots, the bench CSVs — that is not a regular file or whose folder
    cannot be written (each found after a whole sweep, or a read of a FIFO that waits for ever). Returns
    the calibration file's units (none if there is no file yet): a file that does not validate (a
    :class:`CalibrationError` naming file, unit and key — a map beyond the pulses a board puts out, say)
    is refused here too, before the board is opened, for its maps would be kept and uploaded."""
    if not units or len(set(units)) != len(units):
        raise ConfigError(f"{list(units)}: give each unit once", "--unit")
    kinds = [p.kind for p in options.plans]
    if len(set(kinds)) != len(kinds):
        raise ConfigError(f"one sweep per map, got {[k.value for k in kinds]}", "--maps")
    if options.esc is not None and BenchKind.ROTOR not in kinds:
        raise ConfigError(
            "teaches the ESCs new endpoints, so their rotor maps must be swept and fitted again: add rotor "
            f"to --maps (given: {','.join(k.value for k in kinds)}); without it the rotor map kept would be "
            "the one of the old endpoints, unverified",
            "--program-esc",
        )
    check_writable(options.out, f"-o {options.out}")
    outputs: dict[str, Path] = {f"-o {options.out}": options.out}
    for unit in units:
        check_writable(plot_path(options.out, unit))
        outputs[f"the plot {plot_path(options.out, unit)}"] = plot_path(options.out, unit)
        for plan in options.plans:
            csv = options.bench_dir / f"unit{unit}_{plan.kind.value}.csv"
            check_writable(csv, f"--bench-dir {options.bench_dir}")
            relative_source(csv, options.out, f"--bench-dir {options.bench_dir}")  # stored by _save
            outputs[f"--bench-dir {options.bench_dir} ({csv.name})"] = csv
    check_distinct(outputs)  # -o bench/unit0_rotor.csv: the sweep's data, then the file, in one file
    return load_calibration(options.out) if options.out.exists() else CalibrationSet(())


def _not_written(plots: dict[int, Path]) -> str:
    """The end of a failed run's message: no calibration file; the fit plots drawn are kept, said so."""
    kept = f" (the fit plots drawn are kept: {', '.join(str(p) for p in plots.values())})" if plots else ""
    return f"the file was not written{kept}"


RECONNECT_S = 5.0
"""How long (s) :func:`_put_back` waits for a lost board to come back before giving up on it."""


def _put_back(link: BenchLink, previous: dict[int, UnitCalibration]) -> str:
    """Put ``previous`` (unit → set) back on the board, each read back, after a failed upload or
    verification; what the board holds now, in words. The outputs go to rest first (an upload needs the
    board DISARMED); a board that is lost — before or while the sets are put back — is waited for
    :data:`RECONNECT_S` and the put-back started again, at most :data:`PUT_BACK_TRIES` times. Best effort:
    never raises (an interrupt meanwhile gives up, said in the words)."""
    if not previous:
        return "nothing was uploaded; the board keeps its sets"
    units = sorted(previous)
    restored: set[int] = set()
    try:
        for attempt in range(1, PUT_BACK_TRIES + 1):
            try:
                restored |= _put_back_once(link, previous, units)
                break
            except HilError as exc:
                lost = isinstance(exc, LinkError) or not link.client.connected  # a Disarm failed on it, say
                if not lost or attempt == PUT_BACK_TRIES:
                    raise
    except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - said in the words, never raised
        return (
            f"the previous sets of units {units} could not be put back ({exc or type(exc).__name__}): the "
            "board may hold a new set, unverified, or part of one"
        )
    how = f"put back (units {sorted(restored)})" if restored else "still there"
    return f"the board holds the previous sets of units {units}, read back: {how}"


PUT_BACK_TRIES = 3
"""How many times :func:`_put_back` starts again on a board lost meanwhile (each waiting for it)."""


def _put_back_once(link: BenchLink, previous: dict[int, UnitCalibration], units: list[int]) -> set[int]:
    """One pass of :func:`_put_back`: the units whose set had to be uploaded again."""
    client = link.client
    if not client.connected:
        client.wait_for(lambda: client.connected, RECONNECT_S)
    if not client.connected:
        raise LinkError(f"not back within {RECONNECT_S:g} s")
    link.safe()
    restored = set()
    for unit in units:
        if client.download_calibration(unit).to_bytes() == previous[unit].to_bytes():
            continue
        client.upload_calibration(unit, previous[unit])
        if client.download_calibration(unit).to_bytes() != previous[unit].to_bytes():
            raise CalibrationError(f"unit {unit}: the set read back differs from the previous one", "board")
        restored.add(unit)
    return restored


def maps_to_verify(
    swept: list[BenchKind], uploaded: UnitCalibration, held: UnitCalibration
) -> tuple[BenchKind, ...]:
    """The maps of ``uploaded`` a run verifies: every one the upload changes — the swept maps, and each
    map kept (from the calibration file) that differs from the one the board ``held``. A map the board
    already held goes back unchanged: the run neither made nor moved it, and checking it against a unit it
    may not fit (a board's default map on a bench unit, an ESC not yet taught) would fail a run over a map
    it did not touch. A file's map is new to the board, though, however it was made: it used to be uploaded
    unverified (a hold pulse of another unit's file drove its gimbal at full rate under a rate-0 command)."""
    return tuple(k for k in BenchKind if k in swept or getattr(uploaded, k.value) != getattr(held, k.value))


def _verify_plan_text(swept: list[BenchKind], checks: tuple[BenchKind, ...], out: Path) -> str:
    """What a unit's verification covers, and why, in words."""
    why = [f"{k.value} ({'swept' if k in swept else f'kept from {out}, new to the board'})" for k in checks]
    skipped = [k.value for k in BenchKind if k not in checks]
    text = f"verifying {', '.join(why)}"
    if skipped:
        text += f"; not verified: {', '.join(skipped)} (what the board held, unchanged)"
    return text


def _assemble(fits: dict[BenchKind, Fit], entry: UnitEntry | None, board: UnitCalibration) -> UnitCalibration:
    """The fitted maps, the others from the file's unit if it has one, else from the board's set."""
    base = entry.calibration if entry is not None else board
    maps = {k.value: getattr(base, k.value) for k in BenchKind}
    maps.update({k.value: f.map for k, f in fits.items()})
    return UnitCalibration(maps["rotor"], maps["gimbal_rate"], maps["gimbal_angle"])  # type: ignore[arg-type]


def _save(
    existing: CalibrationSet,
    out: Path,
    calibrations: dict[int, UnitCalibration],
    fits: dict[int, dict[BenchKind, Fit]],
    csvs: dict[int, dict[BenchKind, Path]],
) -> Path:
    """Save the calibrated units into ``out``, read again under its lock (:func:`locked`): the units
    another writer saved in it since the run began are kept (the run's units, assembled from ``existing``
    as it was then, replace theirs). Saving the file as read before the sweeps lost them."""
    with locked(out, f"-o {out}"):
        cset = load_calibration(out) if out.exists() else CalibrationSet(())
        for unit, cal in calibrations.items():
            old = existing.unit(unit)
            provenance = dict(old.fits) if old is not None else {}
            for kind, fit in fits[unit].items():
                r = fit.report
                source = relative_source(csvs[unit][kind], out, f"--bench-dir ({csvs[unit][kind]})")
                provenance[kind.value] = FitInfo(source, r.points, r.rms, r.max_abs, r.unit, r.battery_v)
            name = old.name if old is not None else f"unit{unit}"
            cset = cset.with_unit(UnitEntry(unit, name, cal, provenance))
        return save_calibration(cset, out)
