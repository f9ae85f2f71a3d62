"""Replay a recorded phone log through the multi-rate merge, pre-filter and estimator; write what came out.

The core of ``hil replay`` as a function (:func:`replay`), so that other front ends (a later ``--port``
that drives a board with the controller's output) reuse it: options in, a :class:`ReplayResult` out, and
an ``on_step`` hook called with every merged step and its estimate when stepping live.

Two ways to run: as fast as possible (the batch path: vectorised merge and pre-filter, one estimator
loop), or *paced* — each step released at its log time on an injected clock (``WallClock`` for real time,
``LockstepClock`` in tests), through the live path that a real phone stream takes.

Outputs in ``out_dir``: ``estimates.csv`` (docs/formats.md), ``summary.json`` (settings, counters, RMSE,
every interval in which the magnetometer was left out as disturbed, time at rest, the final gyro bias
estimate), and figures: with ground truth the paper's two — the principal angle of the attitude
estimation error and the angular-velocity estimation error — else the estimated attitude (roll/pitch/yaw)
and rates; the magnetometer's rejection intervals shaded on the attitude figures.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from hil.estimation.estimator import Estimate, EstimateBatch
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.inertial import directions_from_dip, directions_from_log, find_still_window, wmm2025
from hil.estimation.metrics import TruthComparison, compare_to_truth
from hil.estimation.multirate import MergePolicy, Merger, MergeStats, merge
from hil.estimation.sensors import (
    KINDS,
    MergedStep,
    MergedSteps,
    SensorKind,
    SensorLog,
    StepFlag,
    flagged_intervals,
)
from hil.logs import read_log
from hil.timing.clock import Clock
from protocol.errors import ConfigError, InputFormatError

Array = NDArray[np.float64]
ESTIMATES_HEADER = "t_s,qw,qx,qy,qz,wx,wy,wz,flags,newton_updates"
ESTIMATES_COMMENT = (
    "# vscmg-hil estimates v1: q body->ENU [w,x,y,z]; w rad/s body; "
    "flags: hil.estimation.sensors.StepFlag bits"
)


@dataclass(frozen=True)
class FieldModel:
    """Where and when a log was recorded, for the WMM2025 field (true-north ENU)."""

    lat_deg: float
    lon_deg: float
    year: float
    height_km: float = 0.0


Plotter = Callable[["ReplayResult", Path], dict[str, Path]]
"""Draws a replay's figures into a directory and returns their files by name (the CLI passes
:func:`hil.plots.estimator.plot_replay`; a library caller passes none or its own)."""


@dataclass(frozen=True)
class ReplayOptions:
    """How to replay. ``preset``: ``"tuned"`` (default) or ``"paper"`` (exactly the paper, incl. its
    1 rad/s body-frame pre-filter); ``config`` overrides the preset entirely. Inertial directions: measured
    from the log (the default), or ``inclination_deg`` given, both with ``declination_deg`` (default 0:
    magnetic north); or a ``field_model`` (true north).
    ``gyro_bias``: ``"still"`` (default) subtracts the mean gyro over the log's initial still window, if it
    has one; ``"none"`` does not. ``window_s``: replay only ``[t0, t1]`` s of the log. ``plotter``: draws the
    figures (none by default)."""

    out_dir: Path
    format: str | None = None
    preset: str = "tuned"
    config: FilterConfig | None = None
    policy: MergePolicy = field(default_factory=MergePolicy)
    inclination_deg: float | None = None
    declination_deg: float = 0.0
    field_model: FieldModel | None = None
    gyro_bias: str = "still"
    window_s: tuple[float, float] | None = None
    plotter: Plotter | None = None
    paced: bool = False
    clock: Clock | None = None
    progress: Callable[[int, int], None] | None = None
    on_step: Callable[[MergedStep, Estimate], None] | None = None


@dataclass
class ReplayResult:
    log: SensorLog
    steps: MergedSteps
    estimates: EstimateBatch
    merge_stats: MergeStats
    config: FilterConfig
    setup: list[str]
    comparison: TruthComparison | None = None
    files: dict[str, Path] = field(default_factory=dict)
    gyro_bias: tuple[float, float, float] | None = None  # the estimate at the end (batch path), rad/s

    @property
    def mag_rejections(self) -> list[tuple[float, float]]:
        """Every interval (s, log time) in which the magnetometer was left out as disturbed."""
        return flagged_intervals(self.estimates.t, self.estimates.flags, StepFlag.MAG_DISTURBED)


def configure(log: SensorLog, options: ReplayOptions) -> tuple[FilterConfig, list[str]]:
    """The filter configuration for this log: preset, inertial directions, gyro bias; and what was done."""
    setup: list[str] = []
    if options.config is not None:
        return options.config, ["configuration given"]
    if options.preset not in ("tuned", "paper"):
        raise ConfigError(f"unknown preset {options.preset!r} (tuned or paper)", "replay preset")
    if options.gyro_bias not in ("still", "none"):
        raise ConfigError(f"must be 'still' or 'none', got {options.gyro_bias!r}", "replay gyro bias")
    bias = (0.0, 0.0, 0.0)
    if options.gyro_bias == "still":
        try:
            still = find_still_window(log)
            gyr = log.streams[SensorKind.GYR]
            sel = (gyr.t >= still.t0) & (gyr.t <= still.t1)
            bias = tuple(float(x) for x in gyr.xyz[sel].mean(axis=0))  # type: ignore[assignment]
            where = f"still window {still.t0:.2f}-{still.t1:.2f} s"
            setup.append(f"gyro bias estimate starts at {np.round(bias, 5).tolist()} rad/s from the {where}")
        except InputFormatError:
            setup.append("no still window: the gyro bias is estimated online from zero")
    declination = options.declination_deg
    if options.field_model is not None:
        fm = options.field_model
        model = wmm2025(fm.lat_deg, fm.lon_deg, fm.year, fm.height_km)
        dip, declination = model.inclination_deg, model.declination_deg
        place = f"{fm.lat_deg:g}, {fm.lon_deg:g}, {fm.year:g}"
        setup.append(f"WMM2025 at {place}: inclination {dip:.2f} deg, declination {declination:.2f} deg")
    elif options.inclination_deg is not None:
        dip = options.inclination_deg
        setup.append(f"inclination {dip:g} deg given")
    else:
        e, how = directions_from_log(log)
        dip = math.degrees(math.asin(float(np.clip(-e[2, 1], -1.0, 1.0))))
        setup.append(f"inertial directions from the log: {how}")
    if options.field_model is None:
        setup.append(f"declination {declination:g} deg" + (" (magnetic north)" if declination == 0 else ""))
    if options.preset == "paper":
        config = FilterConfig.paper(E=directions_from_dip(dip, declination), gyro_bias=bias)
        setup.append("preset paper: W, m, D, Φ and the 1 rad/s body-frame pre-filter of the paper")
    else:
        config = FilterConfig.tuned(declination_deg=declination, gyro_bias=bias)
        setup.append("preset tuned: strapdown-frame pre-filter, horizontal magnetometer, tuned gains")
    return config, setup


def replay(path: Path | str, options: ReplayOptions) -> ReplayResult:
    """Read, merge, filter and write one log; see the module docstring."""
    log = read_log(path, options.format)
    if options.window_s is not None:
        log = log.window(*options.window_s)
    config, setup = configure(log, options)
    steps, stats = merge(log.streams, options.policy)
    first = _first_complete(steps)
    if first:
        setup.append(f"first {first} steps dropped: not every sensor had spoken yet")
        steps = steps.rows(first)
    bias = None
    if options.paced or options.on_step is not None:
        estimates = _run_live(log, steps, stats, config, options)
    else:
        chain = AttitudeFilter(config)
        estimates = chain.run(steps, options.progress)
        bias = tuple(float(x) for x in chain.gyro_bias)
    result = ReplayResult(log, steps, estimates, stats, config, setup, gyro_bias=bias)  # type: ignore[arg-type]
    _score(result)
    options.out_dir.mkdir(parents=True, exist_ok=True)
    result.files["estimates"] = write_estimates(estimates, options.out_dir / "estimates.csv")
    if options.plotter is not None:
        result.files.update(options.plotter(result, options.out_dir))
    result.files["summary"] = _write_summary(result, options.out_dir / "summary.json")
    return result


def _first_complete(steps: MergedSteps) -> int:
    spoken = np.all([np.isfinite(steps.age[:, k]) for k in KINDS], axis=0)
    return int(np.argmax(spoken)) if spoken.any() else 0


def _run_live(
    log: SensorLog, steps: MergedSteps, stats: MergeStats, config: FilterConfig, options: ReplayOptions
) -> EstimateBatch:
    """The live path: samples through a :class:`Merger` in time order, each step paced on the clock."""
    merger = Merger(MergePolicy(**{**asdict(options.policy), "driver": stats.driver,
                                   "failover_order": stats.failover_order}))  # fmt: skip
    chain = AttitudeFilter(config)
    samples = sorted(
        (s for stream in log.streams.values() for s in stream.samples()),
        key=lambda s: (s.t_s, s.kind == stats.driver),
    )
    clock = options.clock
    t0_log = float(steps.t[0]) if len(steps) else 0.0
    t0_clock = clock.now() if clock is not None else 0.0
    out: list[Estimate] = []
    for sample in samples:
        for step in merger.push(sample):
            if step.t < t0_log:
                continue  # before every sensor had spoken (as in the batch path)
            if options.paced and clock is not None:
                clock.sleep_until(t0_clock + (step.t - t0_log))
            estimate = chain.step(step)
            out.append(estimate)
            if options.on_step is not None:
                options.on_step(step, estimate)
            if options.progress is not None and len(out) % 10_000 == 0:
                options.progress(len(out), len(steps))
    if options.progress is not None:
        options.progress(len(out), len(steps))
    n = len(out)
    return EstimateBatch(
        np.array([e.t for e in out]),
        np.array([e.R for e in out]).reshape(n, 3, 3),
        np.array([e.omega for e in out]).reshape(n, 3),
        np.array([e.omega_err for e in out]).reshape(n, 3),
        np.array([int(e.flags) for e in out], dtype=np.int64),
        np.array([e.iterations for e in out], dtype=np.int64),
    )


def _score(result: ReplayResult) -> None:
    truth, est = result.log.truth, result.estimates
    if truth is None or len(est) < 2:
        return
    result.comparison = compare_to_truth(truth.t, truth.R, truth.evaluate, est.t, est.quat, est.omega)


def write_estimates(est: EstimateBatch, path: Path) -> Path:
    """The estimates CSV (docs/formats.md): time, attitude quaternion body → ENU, rate estimate, flags."""
    q = est.quat
    table = np.column_stack([est.t, q, est.omega])
    with path.open("w", encoding="utf-8", newline="\n") as f:
        f.write(ESTIMATES_COMMENT + "\n")
        f.write(ESTIMATES_HEADER + "\n")
        for row, flags, iters in zip(
            table.tolist(), est.flags.tolist(), est.iterations.tolist(), strict=True
        ):
            f.write(",".join(f"{v:.9g}" for v in row) + f",{flags},{iters}\n")
    return path


def _flagged_time(est: EstimateBatch, flag: StepFlag) -> float:
    """Seconds spent in steps carrying ``flag`` (each step counts its own length)."""
    if len(est) < 2:
        return 0.0
    h = np.diff(est.t, prepend=est.t[0])
    return float(h[(est.flags & int(flag)) != 0].sum())


def _write_summary(result: ReplayResult, path: Path) -> Path:
    stats = result.merge_stats
    flags = result.estimates.flags
    summary = {
        "log": result.log.source,
        "format": result.log.format,
        "reader_notes": list(result.log.notes),
        "setup": result.setup,
        "samples": result.log.n_samples,
        "steps": len(result.estimates),
        "merge": {
            "driver": stats.driver.label if stats.driver is not None else None,
            "accepted": stats.accepted,
            "dropped_nan": stats.nan,
            "dropped_duplicate": stats.duplicate,
            "dropped_out_of_order": stats.out_of_order,
            "stale_steps": stats.stale_steps,
            "gaps": stats.gaps,
            "failover_steps": stats.failover_steps,
        },
        "flagged_steps": {
            f.name: int(np.count_nonzero(flags & int(f))) for f in StepFlag if f.name and f != StepFlag.NONE
        },
        "magnetometer_rejected": {
            "intervals_s": [[round(a, 4), round(b, 4)] for a, b in result.mag_rejections],
            "total_s": round(_flagged_time(result.estimates, StepFlag.MAG_DISTURBED), 4),
        },
        "rest_s": round(_flagged_time(result.estimates, StepFlag.REST), 4),
        "gyro_bias_final_rad_s": None if result.gyro_bias is None else list(result.gyro_bias),
        "rmse_deg": None if result.comparison is None else asdict(result.comparison.rmse),
        "rate_rmse_rad_s": None if result.comparison is None else result.comparison.rate_rmse,
        "files": {k: str(v) for k, v in result.files.items()},
    }
    path.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return path
