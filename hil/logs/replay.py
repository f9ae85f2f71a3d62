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

Gaps: where the log's clock (all sensors together) jumps by more than ``max_gap_s`` (default
:data:`MAX_GAP_S`) — a recording paused, or a corrupt timestamp — the log is split and the filter starts
afresh on each part (it never integrates across the gap); each split is reported (``summary.json``
``segments``). A 6-axis log (no magnetometer) runs with gravity alone (the filter's 6-axis mode):
inclination is observed, heading is the gyroscope's integral (reported unobserved, drifting). The
measured field is checked against the field model, and for steadiness
(:func:`hil.estimation.inertial.field_warnings`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.estimation.admission import ReadingLimits, out_of_range
from hil.estimation.estimator import Estimate, EstimateBatch, _concat
from hil.estimation.geomag import GeomagneticField, igrf14
from hil.estimation.inertial import (
    directions_from_log,
    field_warnings,
    find_still_window,
    gives_direction,
    tilt_attitude,
)
from hil.estimation.interface import Estimator, Site
from hil.estimation.metrics import TruthComparison, compare_to_truth
from hil.estimation.multirate import MergePolicy, Merger, MergeStats, merge
from hil.estimation.registry import EstimatorChoice
from hil.estimation.sensors import (
    MAX_PAUSE_S,
    MergedStep,
    MergedSteps,
    SensorKind,
    SensorLog,
    SensorStream,
    StepFlag,
    flagged_intervals,
)
from hil.files.json_text import strict_json
from hil.files.output import make_dir, refuse_others_outputs
from hil.logs import read_log
from hil.logs.acc_units import acc_unit_warning
from hil.logs.file_names import sensor_files_where
from hil.logs.gyro_units import gyro_unit_warning
from hil.logs.rates import RATE_DROP_FACTOR, RateDrop, rate_drops
from hil.timing.clock import Clock
from protocol.errors import ConfigError, InputFormatError

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]
ESTIMATES_HEADER = "t_s,qw,qx,qy,qz,wx,wy,wz,flags,newton_updates"
ESTIMATES_COMMENT = (
    "# vscmg-hil estimates v1: q body->ENU [w,x,y,z]; w rad/s body; "
    "flags: hil.estimation.sensors.StepFlag bits"
)


MAX_GAP_S = MAX_PAUSE_S
"""A jump of the log's clock longer than this (s) splits the replay: the filter restarts after it, as the
live host's does after a pause of its phone (:data:`hil.estimation.sensors.MAX_PAUSE_S`, one rule)."""
MIN_SEGMENT_STEPS = 10
"""A part of a split log shorter than this many merged steps is not run (reported)."""
SAID_PARTS = 3
"""The parts whose reasons the error for a log with no part replayed lists (a ``--max-gap`` below the
sampling step makes a part of every sample)."""
MAX_REPLAY_STEPS = 400_000
"""The most merged steps one replay runs (33 minutes at 200 Hz): a replay holds every step, its estimate
and the figures' data at about 1 kB a step, and this keeps ``hil replay``'s peak memory under 512 MB. A
longer log is refused before it is merged, naming the file: replay a part of it (``window_s``,
``--window``)."""


@dataclass(frozen=True)
class FieldModel:
    """Where and when a log was recorded, for the IGRF-14 field (true-north ENU), any date 1900–2030."""

    lat_deg: float
    lon_deg: float
    year: float
    height_km: float = 0.0


Plotter = Callable[["ReplayResult", Path], dict[str, Path]]
"""Draws a replay's figures into a directory and returns their files by name (the CLI passes
:func:`hil.plots.estimator.plot_replay`; a library caller passes none or its own)."""


REPLAY_ESTIMATOR = EstimatorChoice("variational", {"preset": "tuned"})
"""What ``hil replay`` runs unless told: the variational estimator, tuned on real phone logs."""


@dataclass(frozen=True)
class ReplayOptions:
    """How to replay. ``estimator``: the estimator and its settings (:mod:`hil.estimation.registry`;
    default :data:`REPLAY_ESTIMATOR`, the variational estimator's tuned preset — ``preset = "paper"`` is
    exactly the paper, incl. its 1 rad/s body-frame pre-filter). Inertial directions:
    measured from the log (the default), or ``inclination_deg`` given, both with ``declination_deg``
    (default 0: magnetic north); or a ``field_model`` (true north). ``gyro_bias``: ``"still"`` (default)
    subtracts the mean gyro over the log's initial still window, if it has one; ``"none"`` does not.
    ``window_s``: replay only ``[t0, t1]`` s of the log. ``max_gap_s``: split the log where its clock
    jumps by more. ``limits``: each sensor's range; a reading beyond it is dropped and counted, as a live
    phone's is (:mod:`hil.estimation.admission`). ``plotter``: draws the figures (none by default)."""

    out_dir: Path
    format: str | None = None
    estimator: EstimatorChoice = field(default_factory=lambda: REPLAY_ESTIMATOR)
    policy: MergePolicy = field(default_factory=MergePolicy)
    inclination_deg: float | None = None
    declination_deg: float = 0.0
    field_model: FieldModel | None = None
    gyro_bias: str = "still"
    window_s: tuple[float, float] | None = None
    max_gap_s: float = MAX_GAP_S
    limits: ReadingLimits = field(default_factory=ReadingLimits)
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
    estimator: EstimatorChoice
    site: Site
    setup: list[str]
    comparison: TruthComparison | None = None
    files: dict[str, Path] = field(default_factory=dict)
    gyro_bias: tuple[float, float, float] | None = None  # the estimate at the end (batch path), rad/s
    segments: list[dict[str, float | int | str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    out_of_range: dict[str, int] = field(default_factory=dict)
    """Readings dropped per sensor (by label) as beyond its range (:func:`drop_out_of_range`): ``log``
    holds the rest."""
    skipped_parts: dict[str, int] = field(default_factory=dict)
    """Readings per sensor (by label) in the parts of the log not replayed (``segments``' ``skipped``: a
    part where a sensor is silent, or too short), each part also a warning."""
    rate_drops: list[RateDrop] = field(default_factory=list)
    """The sensors whose rate dropped part-way through the log (:func:`hil.logs.rates.rate_drops`), each
    also a warning: counted in ``summary.json`` (``rate_drops``)."""

    @property
    def samples_read(self) -> int:
        """The readings the log had (in the window replayed), those dropped as beyond range included."""
        return self.log.n_samples + sum(self.out_of_range.values())

    @property
    def mag_rejections(self) -> list[tuple[float, float]]:
        """Every interval (s, log time) in which the magnetometer was left out as disturbed, within the
        parts replayed (:attr:`replayed_spans`): a part that ended with it left out and the next that began
        so were one interval across the gap between them, shaded over the gap in the figures."""
        t, flags = self.estimates.t, self.estimates.flags
        intervals: list[tuple[float, float]] = []
        for first, last in self.replayed_spans or [(-np.inf, np.inf)]:
            inside = (t >= first) & (t <= last)
            intervals += flagged_intervals(t[inside], flags[inside], StepFlag.MAG_DISTURBED)
        return intervals

    @property
    def replayed_spans(self) -> list[tuple[float, float]]:
        """(first, last) estimate time (s, log time) of each part replayed, in order: the estimates are the
        filter's within them only. Between two (a gap, a part not replayed) there is none — a line drawn
        or an estimate interpolated across is two parts' ends joined (:meth:`replayed`)."""
        spans: list[tuple[float, float]] = []
        est_t = self.estimates.t
        for segment in self.segments:
            if "steps" not in segment:
                continue
            t0, t1 = float(segment["t0_s"]), float(segment["t1_s"])
            own = est_t[(est_t >= t0) & (est_t <= t1)]
            if len(own):
                spans.append((float(own[0]), float(own[-1])))
        return spans

    def replayed(self, times: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which ``times`` (s, log time) lie within a replayed part's estimates (:attr:`replayed_spans`):
        the truth is scored there only, and the figures draw errors there only (:mod:`hil.plots.estimator`).
        Across a gap, or over a part not replayed, the estimates are two parts' ends joined by interpolation
        — no estimate the filter made (a turn during a 70 s gap scored 46.7° of RMSE against a log replayed
        perfectly on both sides; the error figure drew that turn as the filter's error)."""
        inside = np.zeros(len(times), bool)
        for first, last in self.replayed_spans:
            inside |= (times >= first) & (times <= last)
        return inside


def configure(log: SensorLog, options: ReplayOptions) -> tuple[EstimatorChoice, Site, list[str]]:
    """The estimator and the site it runs at for this log — inertial directions, gyro bias, the merged
    steps' period, 6-axis or not —, and what was done to find them."""
    refuse_lone_readings(log)  # before the directions measured from the log, which name another sensor
    setup: list[str] = []
    if options.gyro_bias not in ("still", "none"):
        raise ConfigError(f"must be 'still' or 'none', got {options.gyro_bias!r}", "replay gyro bias")
    bias = (0.0, 0.0, 0.0)
    measured = measured_from(log, options.max_gap_s)
    if options.gyro_bias == "still":
        try:
            still = find_still_window(measured)
            gyr = log.streams[SensorKind.GYR]
            sel = (gyr.t >= still.t0) & (gyr.t <= still.t1)
            bias = tuple(float(x) for x in gyr.xyz[sel].mean(axis=0))  # type: ignore[assignment]
            where = f"still window {still.t0:.2f}-{still.t1:.2f} s"
            setup.append(f"gyro bias estimate starts at {np.round(bias, 5).tolist()} rad/s from the {where}")
        except InputFormatError:
            setup.append("no still window: the gyro bias is estimated online from zero")
    for suspect in (gyro_unit_warning(log), acc_unit_warning(log)):  # deg/s, g: warned, never refused
        if suspect is not None:
            logger.warning("%s", suspect)
            setup.append(f"warning: {suspect}")
    declination = options.declination_deg
    model = None
    if options.field_model is not None:
        fm = options.field_model
        model = igrf14(fm.lat_deg, fm.lon_deg, fm.year, fm.height_km)
        dip, declination = model.inclination_deg, model.declination_deg
        place = f"{fm.lat_deg:g}, {fm.lon_deg:g}, {fm.year:.2f}"
        setup.append(f"IGRF-14 at {place}: inclination {dip:.2f} deg, declination {declination:.2f} deg")
    elif options.inclination_deg is not None:
        dip = options.inclination_deg
        setup.append(f"inclination {dip:g} deg given")
    elif log.six_axis:
        dip = 0.0
        setup.append("no magnetometer (6-axis): inclination from gravity; heading NOT observed, it is the")
        setup.append("  gyroscope's integral from an arbitrary start (yaw 0) and drifts with its bias")
    else:
        e, how = directions_from_log(measured)
        dip = math.degrees(math.asin(float(np.clip(-e[2, 1], -1.0, 1.0))))
        setup.append(f"inertial directions from the log: {how}")
    refuse_no_direction(log)  # after the directions measured from the log, which name the first 10 s
    if options.field_model is None and not log.six_axis:
        setup.append(f"declination {declination:g} deg" + (" (magnetic north)" if declination == 0 else ""))
    known: dict[str, object] = {"gyro_bias": bias}
    if log.six_axis:  # 6-axis, started from gravity alone (heading 0)
        known["init"] = tilt_attitude(measured)
        known["magnetometer"] = False
    period = min(stream.median_period() for stream in log.streams.values())
    site = Site.of_dip(dip, declination, period, **known)
    setup.append(options.estimator.describe())
    return options.estimator, site, setup


def measured_from(log: SensorLog, max_gap_s: float) -> SensorLog:
    """``log`` from the first of its parts (:func:`split_at_gaps`) in which every sensor has
    :data:`MIN_SEGMENT_STEPS` samples or more: what the still window, the inertial directions and the
    starting tilt are measured from, at the log's start (:attr:`SensorLog.start`, its first seconds). A
    stray row stamped far before the recording (-1e5 s, -1e160 s: a part of its own, never replayed) was
    taken for its start, and the replay refused as "too few magnetometer samples in the first 10 s (1, at
    least 5 needed)". ``log`` itself when that part is its first (the samples whose time is no number are
    kept either way, as :func:`_up_to` keeps them)."""
    for i, (t0, t1) in enumerate(split_at_gaps(log, max_gap_s)):
        counts = [np.count_nonzero((s.t >= t0) & (s.t <= t1)) for s in log.streams.values()]
        if min(counts) < MIN_SEGMENT_STEPS:
            continue
        if i == 0:
            return log
        kept = {k: ~(s.t < t0) for k, s in log.streams.items()}
        streams = {k: SensorStream(k, s.t[kept[k]], s.xyz[kept[k]]) for k, s in log.streams.items()}
        return SensorLog(streams, log.source, log.format, None, log.notes, log.dropped)
    return log


def field_model_of(options: ReplayOptions) -> GeomagneticField | None:
    """The IGRF-14 field at the options' place and date, if given."""
    fm = options.field_model
    return None if fm is None else igrf14(fm.lat_deg, fm.lon_deg, fm.year, fm.height_km)


def seconds(t: float) -> str:
    """A log time (s) for a message: to the ms, or in 6 significant digits where that would run long (a
    stray row at 1e308 s printed 300 digits)."""
    return f"{t:.3f}" if abs(t) < 1e9 else f"{t:.6g}"


def rate_drop_warning(drop: RateDrop) -> str:
    """What a replay says of one sensor whose rate dropped part-way (:class:`hil.logs.rates.RateDrop`):
    where, for how long, how slow — the estimates there rest on fewer samples (each estimator integrates
    the slow steps through their real length, :mod:`hil.estimation.vqf_adapter`'s too)."""
    return (
        f"{drop.kind.label}: its rate drops part-way through the log: {drop.steps} steps over "
        f"{drop.seconds:.3g} s, from {seconds(drop.first_s)} s on, come more than {RATE_DROP_FACTOR:g} "
        f"times slower than its own {drop.rate_hz:.3g} Hz (as slow as {drop.slowest_hz:.3g} Hz): the "
        "estimates there rest on fewer samples than the rest (each of those steps integrated through its "
        "real length, the gyroscope interpolated across it)"
    )


PINNED_RUN = 10
"""Consecutive samples of one axis at exactly the same large reading (:data:`PINNED_FLOOR`) that are a
sensor clipped at its range, not motion: a real rate or acceleration that large moves by its noise, and by
its own change, from one sample to the next."""
PINNED_FLOOR = {SensorKind.GYR: 4.0, SensorKind.ACC: 19.0}
"""The smallest reading (rad/s, m/s²) a pinned run counts from: just under the smallest range a phone's
gyroscope (±250 °/s, 4.36 rad/s) and accelerometer (±2 g, 19.6 m/s²) clip at; a still phone's quantised
zero or gravity repeats exactly, far below."""


_PINNED_MEANS = {
    SensorKind.GYR: ", the phone turning faster than it measures: the estimates integrate the clipped rate, "
    "not the turn",
    SensorKind.ACC: " (a shock, running): gravity's direction taken from those samples is off",
}


def pinned_warnings(log: SensorLog) -> list[str]:
    """One warning per gyroscope or accelerometer whose readings sit pinned at one large value on an axis
    for :data:`PINNED_RUN` samples or more (:data:`PINNED_FLOOR`): clipped at its range — a spin faster than
    the gyroscope measures, a shock beyond the accelerometer's. The estimator integrates the clipped value
    as if it were the motion (a gyroscope pinned at 8.73 rad/s for 2 s turned the estimate through 17.5 rad
    of the phone's true, unknown turn), and the replay said nothing. Said, with where and for how long."""
    out = []
    for kind, floor in PINNED_FLOOR.items():
        stream = log.streams.get(kind)
        if stream is None or len(stream) < PINNED_RUN:
            continue
        xyz = stream.xyz
        same = (xyz[1:] == xyz[:-1]) & (np.abs(xyz[1:]) >= floor)  # (n-1, 3): equal to the one before
        pinned = np.zeros(len(stream), bool)
        largest = 0.0  # the largest pinned value (its magnitude), for the message
        for axis in range(3):
            edges = np.diff(np.concatenate([[0], same[:, axis].astype(np.int8), [0]]))
            for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
                if stop - start + 1 >= PINNED_RUN:  # samples start..stop (``same[i]``: sample i + 1)
                    pinned[start : stop + 1] = True
                    largest = max(largest, abs(float(xyz[start, axis])))
        if not pinned.any():
            continue
        times = stream.t[pinned]
        out.append(
            f"{kind.label}: {int(pinned.sum())} samples pinned at one value, up to {largest:.6g} {kind.unit} "
            f"({seconds(float(np.nanmin(times)))}-{seconds(float(np.nanmax(times)))} s): the sensor clipped "
            f"at its range{_PINNED_MEANS[kind]}"
        )
    return out


_SILENT_MEANS = {
    SensorKind.GYR: "the filter goes on without a rate there (its steps flagged GYR_STALE): the attitude "
    "follows the accelerometer and magnetometer alone and lags every turn, by tens of degrees in motion",
    SensorKind.ACC: "the inclination there rests on the gyroscope's integral alone",
    SensorKind.MAG: "the heading there rests on the gyroscope's integral alone (it drifts)",
}
SAID_SILENCES = 5
"""The silences of one sensor a warning names one by one (their number and total length: all of them)."""


EDGE_STAGGER_S = MAX_PAUSE_S
"""s: how much later than the others a sensor may start, or how much earlier stop, before it is said as a
silence (:func:`silence_warnings`): a phone's sensors start and stop a fraction of a second apart (the
shipped Sensor Logger export's: 0.23 s), which is no silence to warn of; longer than a pause of the whole
log (:data:`MAX_GAP_S`), it is."""


def silence_warnings(log: SensorLog, stale_after_s: float) -> list[str]:
    """One warning per sensor that falls silent for longer than ``stale_after_s`` (s: the merge's
    :attr:`~hil.estimation.multirate.MergePolicy.stale_after_s`, beyond which its held sample is not used)
    while the others go on sampling. The log's clock does not jump there (:func:`split_at_gaps` sees every
    sensor's times together), so the filter is not restarted: it runs on through the silence on the other
    sensors. The merge's stale count was the only trace, and it is warned about only beyond
    :data:`LOSS_WARNED` of the steps: a gyroscope silent for 5 s of a 200 s BROAD trial (2.4 % of its
    steps) left the estimates 89° off in motion with not a word. Said, with where and for how long.

    A sensor that starts later than the others, or stops earlier, by more than :data:`EDGE_STAGGER_S`
    while they sample is said too, in a warning of its own (:func:`_edge_silences`): a magnetometer that
    stopped 20 s before the end left the heading on the gyroscope alone, and one that started 20 s after
    the others left those 20 s unreplayed, with not a word in the warnings."""
    out: list[str] = []
    finite = {kind: np.unique(s.t[np.isfinite(s.t)]) for kind, s in log.streams.items()}
    if len(finite) < 2:  # no other sensor to go on
        return out
    for kind in sorted(finite):
        t = finite[kind]
        if t.size < 1:
            continue
        others = np.concatenate([times for other, times in finite.items() if other != kind])
        others.sort()
        silent = [
            (float(t[i]), float(t[i + 1]))
            for i in np.flatnonzero(np.diff(t) > stale_after_s)
            if _others_sample(others, float(t[i]), float(t[i + 1]), stale_after_s) > stale_after_s
        ]
        if silent:
            spans = ", ".join(f"{seconds(a)}-{seconds(b)} s" for a, b in silent[:SAID_SILENCES])
            more = f" and {len(silent) - SAID_SILENCES} more" if len(silent) > SAID_SILENCES else ""
            total = sum(b - a for a, b in silent)
            out.append(
                f"{kind.label}: silent for {total:.3g} s in {len(silent)} stretch(es) longer than "
                f"{stale_after_s:g} s ({spans}{more}) while the other sensors go on: {_SILENT_MEANS[kind]}"
            )
        out += _edge_silences(kind, t, others, stale_after_s)
    return out


def _others_sample(others: NDArray[np.float64], a: float, b: float, stale_after_s: float) -> float:
    """How long (s) the other sensors go on sampling over ``(a, b)`` (s): the steps between their samples
    there (and ``a``, ``b``) no longer than ``stale_after_s``, summed. A pause of the whole log (its
    sensors' last samples staggered by a few ms) is no one sensor's silence, and is said as a gap if
    longer."""
    inside = others[np.searchsorted(others, a, "right") : np.searchsorted(others, b, "left")]
    steps = np.diff(np.concatenate([[a], inside, [b]]))
    return float(steps[steps <= stale_after_s].sum())


def _edge_silences(
    kind: SensorKind, t: NDArray[np.float64], others: NDArray[np.float64], stale_after_s: float
) -> list[str]:
    """The warnings for a sensor (its finite times ``t``, s, sorted) that starts after the other sensors
    (their times ``others``) or stops before them by more than :data:`EDGE_STAGGER_S`, while they sample
    (:func:`_others_sample`). A gyroscope's or accelerometer's early end is not said here: the replay cuts
    the log there and says so (:func:`needed_end`, :func:`steerable_end`)."""
    out: list[str] = []
    first, last = float(t[0]), float(t[-1])
    if others.size and first - float(others[0]) > EDGE_STAGGER_S:
        a = float(others[0])
        if _others_sample(others, a, first, stale_after_s) > EDGE_STAGGER_S:
            out.append(
                f"{kind.label}: silent for its first {first - a:.3g} s ({seconds(a)}-{seconds(first)} s): it "
                f"starts after the other sensors, which sample from {seconds(a)} s: nothing before "
                f"{seconds(first)} s is replayed (an estimate starts once every sensor has spoken)"
            )
    if kind is SensorKind.MAG and others.size and float(others[-1]) - last > EDGE_STAGGER_S:
        b = float(others[-1])
        if _others_sample(others, last, b, stale_after_s) > EDGE_STAGGER_S:
            out.append(
                f"{kind.label}: silent for its last {b - last:.3g} s ({seconds(last)}-{seconds(b)} s): it "
                f"stops before the other sensors, which sample until {seconds(b)} s: {_SILENT_MEANS[kind]}"
            )
    return out


def split_at_gaps(log: SensorLog, max_gap_s: float) -> list[tuple[float, float]]:
    """``[t0, t1]`` parts of the log between jumps of its clock (every sensor's times together) longer
    than ``max_gap_s``; one part when there is none."""
    times = np.unique(np.concatenate([s.t[np.isfinite(s.t)] for s in log.streams.values()]))
    if not times.size:
        return []
    cut = np.flatnonzero(np.diff(times) > max_gap_s)
    starts = np.concatenate([[times[0]], times[cut + 1]])
    ends = np.concatenate([times[cut], [times[-1]]])
    return [(float(a), float(b)) for a, b in zip(starts, ends, strict=True)]


def before_clock_restart(
    log: SensorLog, max_gap_s: float, kept: str = "driving the board with the stretch before it"
) -> tuple[SensorLog, str | None]:
    """``log`` up to where its clock first goes back by more than ``max_gap_s`` (a recording restarted, its
    clock from zero again, appended to the first), each sensor's samples before its own first such step;
    and what was left out, said for the operator (None: the clock never went back so far). A board is
    driven on the clock: the stretch after the restart, stamped over the first one's times, was released
    all at once behind it, and the run said ``completed`` driven by the first stretch alone, without a
    word (:func:`split_at_gaps` sees only jumps forward: it takes the times sorted). ``kept``: what is
    done with the stretch before, for the message (a batch replay replays it)."""
    cut: dict[SensorKind, int] = {}
    for kind, stream in log.streams.items():
        t = stream.t
        finite = np.flatnonzero(np.isfinite(t))
        if finite.size < 2:
            continue
        restart = _clock_restart(t[finite], max_gap_s)
        if restart is not None:
            cut[kind] = int(finite[restart])
    if not cut:
        return log, None
    streams = {
        kind: SensorStream(kind, s.t[: cut[kind]], s.xyz[: cut[kind]]) if kind in cut else s
        for kind, s in log.streams.items()
    }
    left_out = sum(len(s) - len(streams[k]) for k, s in log.streams.items())
    first = min(cut.items(), key=lambda item: item[1])
    kind, at = first
    stream = log.streams[kind]
    was = float(np.nanmax(stream.t[:at]))
    said = (
        f"the log's clock goes back from {was:.3f} s to {float(stream.t[at]):.3f} s ({kind.name}, sample "
        f"{at}: a recording restarted); {kept} ({left_out} samples after it left out)"
    )
    trimmed = SensorLog(streams, log.source, log.format, log.truth, log.notes, log.dropped)
    return trimmed, said


RESTART_RUN = 5
"""Samples a clock's level is judged over, before a step back and after it (:func:`_clock_restart`)."""


def _clock_restart(times: NDArray[np.float64], max_gap_s: float) -> int | None:
    """The index of the first sample (of one stream's finite ``times``, in recorded order) at which the
    clock restarted: more than ``max_gap_s`` below the level before it (the median of the
    :data:`RESTART_RUN` samples before), and the next ones going on from there — nearer to it than to that
    level. A stray stamped far ahead, and the stream that resumes after it, is no restart; nor is one stray
    stamped far behind, after which the stream resumes at its level; nor a step back with fewer than
    :data:`RESTART_RUN` samples from it on (a stray last row: a batch replay leaves it out as a part of
    its own, counted), or before it (a stray first row, at 1e160 s: the level of that one row was taken
    for a first stretch, the whole recording after it for a restart, and the replay refused as "the
    accelerometer has 1 reading(s) with a time (at 1e+160 s)")."""
    for i in np.flatnonzero(times[1:] < times[:-1] - max_gap_s) + 1:
        if i < RESTART_RUN:  # too few before it to tell a first stretch from strays ahead: no restart
            continue
        if i + RESTART_RUN > len(times):  # too few after it to tell a restart from a stray: no restart
            break
        level = float(np.median(times[max(0, i - RESTART_RUN) : i]))
        if times[i] < level - max_gap_s and np.all(times[i : i + RESTART_RUN] < (level + times[i]) / 2):
            return int(i)
    return None


def steerable_end(log: SensorLog) -> tuple[SensorLog, str | None]:
    """``log`` up to the last time both the gyroscope and the accelerometer speak (the host steers only with
    both; the magnetometer may go) when the rest is longer than :data:`TRIM_S`, and what was left out,
    said for the operator (None: nothing was). A
    recording whose gyroscope ends 0.8 s before its accelerometer played on to the accelerometer's end,
    and the run ended "lost: phone lost … no gyroscope reading came", status 3, though the recording had
    simply ended."""
    ended = needed_end(log)
    if ended is None:
        return log, None
    needed, sensor, longest = ended
    said = (
        f"driving the board until {needed:.3f} s, where the log's {sensor} ends ({longest.name} goes on "
        f"{log.end - needed:.2f} s more: the host steers only with both)"
    )
    return _up_to(log, needed), said


def needed_end(log: SensorLog) -> tuple[float, str, SensorKind] | None:
    """Where (s) the log's gyroscope or accelerometer — the two an estimate needs; the magnetometer may go —
    ends, which of them ("gyroscope", "accelerometer") and the sensor that goes on longest, when the log
    goes on more than :data:`TRIM_S` after it; None when it does not. Beyond that end every step would
    be the other sensors' alone, the missing one held stale: a gyroscope of one row beside 8 s of the
    others replayed ~400 steps, one of them with a gyroscope reading."""
    ends = {k: float(np.nanmax(np.where(np.isfinite(s.t), s.t, np.nan))) for k, s in log.streams.items()}
    needed = min(ends[SensorKind.GYR], ends[SensorKind.ACC])
    if not log.end - needed > TRIM_S:  # shorter than a gap: played whole, as ever
        return None
    sensor = "gyroscope" if ends[SensorKind.GYR] == needed else "accelerometer"
    return needed, sensor, max(ends, key=lambda k: ends[k])


TRIM_S = 0.25
"""s: :func:`steerable_end` cuts a tail only longer than this — the host's own bound for a phone's silence
(``hil.runtime.faults.STALE_AFTER_S``): a shorter one never made a gap, and is played whole."""


def _up_to(log: SensorLog, t1: float) -> SensorLog:
    """``log``'s samples up to ``t1`` (s) — and those whose time is no number: the host's admission drops
    and counts them, as ever (a time window would leave them out uncounted)."""
    streams = {k: SensorStream(k, s.t[~(s.t > t1)], s.xyz[~(s.t > t1)]) for k, s in log.streams.items()}
    truth = None if log.truth is None else log.truth.window(-math.inf, t1)
    return SensorLog(streams, log.source, log.format, truth, log.notes, log.dropped)


def replay(path: Path | str, options: ReplayOptions) -> ReplayResult:
    """Read, merge, filter and write one log; see the module docstring."""
    if not (math.isfinite(options.max_gap_s) and options.max_gap_s > 0):
        raise ConfigError(f"must be a positive number of seconds, got {options.max_gap_s!r}", "max_gap_s")
    refuse_others_outputs(options.out_dir, "estimates.csv", "a replay's outputs")  # before the work
    log = read_log(path, options.format)
    if options.window_s is not None:
        log = log.window(*options.window_s)
    # a clock that goes back (a recording restarted, or one file's clock): the samples after it, stamped
    # over earlier times, were merged where they fell — dropped as out of order up to the first stretch's
    # end, and beyond it taken as readings of those times
    whole = log
    log, restarted = before_clock_restart(log, options.max_gap_s, "replaying the stretch before it")
    after_restart = {k.label: len(whole.streams[k]) - len(s) for k, s in log.streams.items()}
    log, beyond = drop_out_of_range(log, options.limits)
    estimator, site, setup = configure(log, options)
    warnings = field_warnings(log, field_model_of(options))
    if any(beyond.values()):
        counts = ", ".join(f"{label} {n}" for label, n in beyond.items() if n)
        warnings.append(
            f"{sum(beyond.values())} readings beyond their sensor's range dropped ({counts}): "
            f"a phone measures at most {_ranges(options.limits)}"
        )
    if restarted is not None:
        warnings.append(restarted)
    slowed = rate_drops(log, options.max_gap_s)
    warnings += [rate_drop_warning(drop) for drop in slowed]
    warnings += pinned_warnings(log)
    warnings += silence_warnings(log, options.policy.stale_after_s)
    parts = split_at_gaps(log, options.max_gap_s)
    parts_said = len(warnings)  # the warnings from here on are the parts'
    all_steps, all_estimates, segments = [], [], []
    stats = MergeStats()
    if len(parts) > 1:  # a part is a span of time: a sample whose time is no number is in none of them
        for kind, stream in log.streams.items():
            stats.nan[kind.label] += int(np.count_nonzero(~np.isfinite(stream.t)))
    bias: tuple[float, float, float] | None = None
    total_steps = 0
    skipped: dict[str, int] = {k.label: after_restart.get(k.label, 0) for k in log.kinds}
    for i, (t0, t1) in enumerate(parts):
        segment: dict[str, float | int | str] = {"t0_s": t0, "t1_s": t1}
        gap = ""
        if i:
            segment["gap_before_s"] = t0 - parts[i - 1][1]
            gap = (
                f"the log's clock jumps by {t0 - parts[i - 1][1]:.6g} s at {seconds(parts[i - 1][1])} s "
                f"(> {options.max_gap_s:g} s)"
            )
        segments.append(segment)
        in_part = {k.label: int(np.count_nonzero((s.t >= t0) & (s.t <= t1))) for k, s in log.streams.items()}
        why = None if all(in_part.values()) else "not every sensor speaks in it"
        if why is None:
            part = log.window(t0, t1) if len(parts) > 1 else log
            ended = needed_end(part)
            if ended is not None:  # its tail beyond: the other sensors' alone, left out and counted
                end, sensor, longest = ended
                tail = {k.label: int(np.count_nonzero(s.t > end)) for k, s in part.streams.items()}
                part = _up_to(part, end)
                for label, n in tail.items():
                    skipped[label] += n
                ends = f"the log's {sensor} ends at {seconds(end)} s ({longest.name} on to {seconds(t1)} s)"
                warnings.append(
                    f"{ends}: {t1 - end:.3g} s not replayed, an estimate needs both the gyroscope and the "
                    f"accelerometer: its {sum(tail.values())} samples are left out "
                    f"({', '.join(f'{label} {n}' for label, n in tail.items())})"
                )
                in_part = {label: n - tail[label] for label, n in in_part.items()}
            _check_length(part, total_steps, log.source)
            steps, seg_stats = merge(part.streams, options.policy)
            first = _first_complete(steps, log)
            if first:
                where = f" of part {i}" if len(parts) > 1 else ""
                setup.append(f"first {first} steps{where} dropped: not every sensor had spoken yet")
                steps = steps.rows(first)
            if len(steps) < MIN_SEGMENT_STEPS:
                why = f"{len(steps)} steps (fewer than {MIN_SEGMENT_STEPS})"
                if ended is not None:
                    why += f": {ends}"
                lost = merge_warnings(replace(seg_stats, stale_steps={}))  # what the merge dropped, and why
                if lost:  # rows in reverse time order: all but one dropped, and said so
                    why += ": " + "; ".join(lost)
        if why is not None:  # its samples counted and said, never lost without a word
            segment["skipped"] = why
            for label, n in in_part.items():
                skipped[label] += n
            counts = ", ".join(f"{label} {n}" for label, n in in_part.items())
            span = f"{seconds(t0)}-{seconds(t1)} s"
            n = sum(in_part.values())
            left_out = f"its {n} samples are left out" if n != 1 else "its 1 sample is left out"
            warnings.append(
                (f"{gap}: " if gap else "")
                + f"the part {span} is not replayed ({why}): {left_out} ({counts})"
            )
            continue
        if gap:
            warnings.append(f"{gap}: the filter restarts there, it does not integrate across")
        segment["steps"] = len(steps)
        total_steps += len(steps)
        _check_length(part, total_steps, log.source, merged=True)
        _add_stats(stats, seg_stats)
        chain = _bounded(estimator.build(site))
        if options.paced or options.on_step is not None:
            estimates = _run_live(part, steps, seg_stats, chain, options)
        else:
            estimates = chain.run(steps, options.progress)
            b = chain.gyro_bias  # the last part's estimate at its end
            bias = (float(b[0]), float(b[1]), float(b[2]))
        all_steps.append(steps)
        all_estimates.append(estimates)
    if not all_estimates:  # each part's reason said: a file in reverse time order is no silent sensor
        raise InputFormatError(
            "no part of the log has every sensor speaking for long enough ("
            + "; ".join(warnings[parts_said:][:SAID_PARTS])
            + (f"; and {len(parts) - SAID_PARTS} more parts" if len(parts) > SAID_PARTS else "")
            + ")",
            log.source,
        )
    warnings += merge_warnings(stats)
    steps = all_steps[0] if len(all_steps) == 1 else _concat_steps(all_steps)
    estimates = all_estimates[0] if len(all_estimates) == 1 else _concat(all_estimates)
    result = ReplayResult(
        log,
        steps,
        estimates,
        stats,
        estimator,
        site,
        setup,
        segments=segments,
        warnings=warnings,
        gyro_bias=bias,
        out_of_range=beyond,
        skipped_parts=skipped,
        rate_drops=slowed,
    )
    _score(result)
    make_dir(options.out_dir)
    clear_outputs(options.out_dir)
    result.files["estimates"] = write_estimates(estimates, options.out_dir / "estimates.csv")
    if options.plotter is not None:
        result.files.update(options.plotter(result, options.out_dir))
    result.files["summary"] = _write_summary(result, options.out_dir / "summary.json")
    return result


REPLAY_OUTPUTS = (
    "estimates.csv",
    "summary.json",
    "attitude.png",
    "rates.png",
    "attitude_error.png",
    "rate_error.png",
)
"""Every file a replay writes in its ``out_dir``: its estimates and summary, and the figures
(``hil.plots.estimator.plot_replay``'s; tests/test_replay_beside_stale_outputs.py holds them equal)."""


def clear_outputs(out_dir: Path) -> None:
    """Remove what an earlier replay left in ``out_dir`` (:data:`REPLAY_OUTPUTS` only, nothing else in
    the folder) before this one writes its own: a replay without plots, or with a log that has no ground
    truth, left the earlier replay's figures beside its summary — one folder, two replays. A name that is
    there but not a file (a folder) is left for the write to refuse; one that cannot be removed is a
    :class:`ConfigError` naming it."""
    for name in REPLAY_OUTPUTS:
        path = out_dir / name
        if path.is_symlink() or path.is_file():
            try:
                path.unlink()
            except FileNotFoundError:
                pass
            except OSError as exc:
                raise ConfigError(
                    f"cannot remove an earlier replay's output: {exc.strerror or exc}", str(path)
                ) from exc


def drop_out_of_range(log: SensorLog, limits: ReadingLimits) -> tuple[SensorLog, dict[str, int]]:
    """``log`` without the readings the live path's admission drops as beyond their sensor's range
    (:func:`hil.estimation.admission.out_of_range`: a value that parses but no phone can measure, 1e160
    rad/s, say), and how many each sensor lost (by label). One such reading held for a step would poison
    the still window's means and the filter's state for the rest of the log. A sensor left with none is
    an :class:`InputFormatError` naming the log."""
    beyond: dict[str, int] = {}
    streams: dict[SensorKind, SensorStream] = {}
    for kind, stream in log.streams.items():
        drop = out_of_range(kind, stream.t, stream.xyz, limits)
        beyond[kind.label] = int(np.count_nonzero(drop))
        streams[kind] = (
            stream if not beyond[kind.label] else SensorStream(kind, stream.t[~drop], stream.xyz[~drop])
        )
        if beyond[kind.label] and not len(streams[kind]):
            raise InputFormatError(
                f"every {kind.name} reading ({beyond[kind.label]}) is beyond the sensor's range "
                f"(|value| > {limits.limit(kind):g} {kind.unit}){_UNIT_HINTS[kind]}",
                sensor_files_where(log, _FILE_STEMS[kind]),
            )
    if not any(beyond.values()):
        return log, beyond
    for label, n in beyond.items():
        if n:
            logger.warning("%s: %d %s readings beyond the sensor's range dropped", log.source, n, label)
    return replace(log, streams=streams), beyond


_FILE_STEMS = {SensorKind.GYR: "[Gg]yro", SensorKind.ACC: "[Aa]ccel", SensorKind.MAG: "[Mm]agnet"}
"""Each sensor's files, as :func:`hil.logs.file_names.sensor_files_where` finds them in a log's notes."""
_UNIT_HINTS = {
    SensorKind.GYR: ": a gyroscope in mdeg/s or another unit? convert it to rad/s",
    SensorKind.ACC: ": an accelerometer in mg or cm/s^2? convert it to m/s^2",
    SensorKind.MAG: ": a magnetometer in nT (the Earth's field is 20-70 uT, 20 000-70 000 nT)? convert it "
    "to uT (divide by 1000)",
}
"""What a sensor none of whose readings is within its range most likely reads in."""


_DIRECTION_SENSORS = (SensorKind.ACC, SensorKind.MAG)
"""The sensors whose readings are directions (gravity, the field): :func:`refuse_no_direction`."""
_NO_DIRECTION_HINTS = {
    SensorKind.ACC: ": gravity's direction cannot be told, and the attitude with it",
    SensorKind.MAG: ": heading cannot be observed; remove its file to replay 6-axis (heading unobserved)",
}


def refuse_no_direction(log: SensorLog) -> None:
    """An :class:`InputFormatError` naming its file when the accelerometer or the magnetometer has no
    reading that gives a direction — every one 0, 0, 0 or no number: the phone has no such sensor, or it
    never started. Measured from the log, the inertial directions refuse such a sensor already (naming
    its first 10 s); given (``--inclination``, the hint of that error, or ``--lat/--lon/--date``), an
    all-zero magnetometer replayed every step with it left out as disturbed, ``summary.json`` saying the
    heading "observed (magnetometer)", and an all-zero accelerometer replayed with no gravity, warned of
    only as a unit in g."""
    for kind in _DIRECTION_SENSORS:
        stream = log.streams.get(kind)
        if stream is not None and len(stream) and not gives_direction(stream.xyz).any():
            raise InputFormatError(
                f"every {kind.name} reading ({len(stream)}) is zero or no number: it gives no direction "
                f"(the phone has no such sensor, or it never started){_NO_DIRECTION_HINTS[kind]}",
                sensor_files_where(log, _FILE_STEMS[kind]),
            )


MIN_TIMED_READINGS = 2
"""The fewest readings with a time a sensor's stream holds: one reading spans no time (a gyroscope's
gives no motion to integrate, an accelerometer's or magnetometer's one direction at one instant)."""
_SENSOR_NAMES = {SensorKind.GYR: "gyroscope", SensorKind.ACC: "accelerometer", SensorKind.MAG: "magnetometer"}
_LONE_HINTS = {
    SensorKind.GYR: ": the estimator has no rates to integrate (the export cut short?)",
    SensorKind.ACC: ": gravity's direction is not followed (the export cut short?)",
    SensorKind.MAG: ": heading cannot be observed; remove its file to replay 6-axis (heading unobserved)",
}


def refuse_lone_readings(log: SensorLog) -> None:
    """An :class:`InputFormatError` naming its file when a sensor holds fewer than
    :data:`MIN_TIMED_READINGS` readings with a finite time. A gyroscope file of one row beside normal
    ones replayed every step on the others' samples, its one reading held stale, and said "completed"; an
    accelerometer of one row was refused as "too few magnetometer samples"."""
    for kind, stream in log.streams.items():
        timed = np.flatnonzero(np.isfinite(stream.t))
        if not 0 < timed.size < MIN_TIMED_READINGS:  # none: the log's span refuses it (SensorLog.start)
            continue
        at = ", ".join(f"{seconds(float(t))} s" for t in stream.t[timed])
        raise InputFormatError(
            f"the {_SENSOR_NAMES[kind]} has {timed.size} reading(s) with a time (at {at}): fewer than "
            f"{MIN_TIMED_READINGS} span no time{_LONE_HINTS[kind]}",
            sensor_files_where(log, _FILE_STEMS[kind]),
        )


def _ranges(limits: ReadingLimits) -> str:
    return (
        f"±{limits.limit(SensorKind.GYR):g} rad/s, ±{limits.limit(SensorKind.ACC):.4g} m/s², "
        f"±{limits.limit(SensorKind.MAG):g} µT"
    )


LOSS_WARNED = 0.05
"""A sensor that loses more than this fraction of its samples to the merge's drops, or is stale on more
than this fraction of the steps, is warned about: a few drops are a phone's hiccups, more is a log whose
rows are out of order or whose clock is broken, and its estimates rest on the other sensors."""


_LOSS_CAUSES = {
    "nan": "readings or times that are no number (the reader's notes say which rows, and why)",
    "duplicate": "its clock repeats times",
    "out_of_order": "its rows are not in time order, or its clock is broken",
}
"""What each of the merge's drop reasons says of a log, for :func:`merge_warnings`."""


def merge_warnings(stats: MergeStats) -> list[str]:
    """The warnings a replay's merge counters call for (:data:`LOSS_WARNED`), one per sensor and kind."""
    out = []
    for label in stats.accepted:
        counts = {
            reason: getattr(stats, reason).get(label, 0) for reason in ("nan", "duplicate", "out_of_order")
        }
        lost = sum(counts.values())
        total = lost + stats.accepted[label]
        if total and lost > LOSS_WARNED * total:
            why = ", ".join(f"{n} {reason.replace('_', ' ')}" for reason, n in counts.items() if n)
            causes = "; ".join(_LOSS_CAUSES[reason] for reason, n in counts.items() if n)
            out.append(
                f"{label}: {lost} of its {total} samples dropped ({why}): {causes}; the estimates rest on "
                "what is left"
            )
        stale = stats.stale_steps.get(label, 0)
        if stats.steps and stale > LOSS_WARNED * stats.steps and stats.accepted[label]:
            out.append(f"{label}: stale (no fresh sample) on {stale} of {stats.steps} steps")
    return out


def merge_stats_of(counts: Mapping[str, Any]) -> MergeStats:
    """A merge's counters from their ``summary.json`` form (:meth:`MergeStats.as_dict`: a run's
    ``phone_merge``), for :func:`merge_warnings`: ``hil replay --port`` warns of what its run's merge
    counted as the batch replay of the same log does."""
    dropped = counts.get("dropped", {})
    return MergeStats(
        accepted=dict(counts.get("accepted", {})),
        nan=dict(dropped.get("nan", {})),
        duplicate=dict(dropped.get("duplicate", {})),
        out_of_order=dict(dropped.get("out_of_order", {})),
        stale_steps=dict(counts.get("stale_steps", {})),
        steps=int(counts.get("steps", 0)),
        gaps=int(counts.get("gaps", 0)),
        failover_steps=int(counts.get("failover_steps", 0)),
    )


def _check_length(part: SensorLog, steps: int, source: str, merged: bool = False) -> None:
    """Refuse a replay of more than :data:`MAX_REPLAY_STEPS` steps: before a part is merged, from its
    busiest sensor's samples (the driver's samples are its steps; a failover adds a few) added to the
    ``steps`` run so far — so that a long log is refused before its steps are built; after, from the count
    itself."""
    if not merged:
        steps += max((len(s) for s in part.streams.values()), default=0)
    if steps > MAX_REPLAY_STEPS:
        what = "steps" if merged else "steps (its busiest sensor's samples)"
        raise InputFormatError(
            f"{steps} {what} to replay, more than {MAX_REPLAY_STEPS} at once: replay a part of it "
            "(--window T0 T1)",
            source,
        )


def _add_stats(total: MergeStats, part: MergeStats) -> None:
    """Add one part's merge counters to the run's (the first part's roles are the run's)."""
    total.absorb(part)
    if total.driver is None:
        total.driver, total.failover_order = part.driver, part.failover_order


def _bounded(chain: Estimator) -> Estimator:
    """``chain`` with a user's estimator's calls — its batch ``run`` too — on a thread of its own, each
    waited for its bound (:func:`hil.bounded_estimator.with_bounded_calls`, as a run's are): a plugin whose
    ``run`` never returned hung ``hil replay`` until it was killed; now it is a
    :class:`~hil.plugins.PluginTimeout` naming the call. ``hil``'s own estimator is called directly."""
    from hil.bounded_estimator import with_bounded_calls  # threads: imported only when replaying

    return with_bounded_calls(chain)


def _concat_steps(parts: list[MergedSteps]) -> MergedSteps:
    names = ("t", "gyr", "acc", "mag", "age", "fresh", "flags")
    return MergedSteps(*(np.concatenate([getattr(p, name) for p in parts]) for name in names))


def _first_complete(steps: MergedSteps, log: SensorLog) -> int:
    spoken = np.all([np.isfinite(steps.age[:, k]) for k in log.kinds], axis=0)
    return int(np.argmax(spoken)) if spoken.any() else 0


def _run_live(
    log: SensorLog, steps: MergedSteps, stats: MergeStats, chain: Estimator, options: ReplayOptions
) -> EstimateBatch:
    """The live path: samples through a :class:`Merger` in time order into the estimator ``chain``, each
    step paced on the clock."""
    policy = {**asdict(options.policy), "driver": stats.driver, "failover_order": stats.failover_order}
    merger = Merger(MergePolicy(**policy))
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
    evaluate = result.replayed(truth.t)
    if truth.evaluate is not None:
        evaluate &= np.asarray(truth.evaluate, bool)
    result.comparison = compare_to_truth(truth.t, truth.R, evaluate, est.t, est.quat, est.omega)
    if result.comparison.rmse.n == 0:  # said, not an RMSE of NaN "over 0 samples" left to be puzzled over
        result.warnings.append(
            f"the ground truth ({truth.t[0]:.3f}-{truth.t[-1]:.3f} s) overlaps none of the estimates "
            f"({est.t[0]:.3f}-{est.t[-1]:.3f} s) where it is evaluated: nothing scored (its clock another "
            "than the log's, or its time alignment off?)"
        )


def write_estimates(est: EstimateBatch, path: Path) -> Path:
    """The estimates CSV (docs/formats.md): time, attitude quaternion body → ENU, rate estimate, flags.

    Formatted :data:`_WRITE_ROWS` rows at a time (one ``%`` per block: twice as fast as a row at a time),
    each block turned into Python numbers on its own: the whole table as Python objects would cost ~320
    bytes a step, more than the estimates themselves. ``t_s`` is written to the µs whatever the clock's
    origin (:func:`time_digits`); the other columns to 9 significant digits."""
    row = f"%.{time_digits(est.t)}g," + ",".join(["%.9g"] * 7) + ",%d,%d\n"
    quat = est.quat
    with path.open("w", encoding="utf-8", newline="\n") as f:
        f.write(ESTIMATES_COMMENT + "\n")
        f.write(ESTIMATES_HEADER + "\n")
        for start in range(0, len(est), _WRITE_ROWS):
            stop = min(start + _WRITE_ROWS, len(est))
            block = np.empty((stop - start, 10), dtype=object)  # t, q (4), Ω (3), flags, iterations
            block[:, 0], block[:, 1:5] = est.t[start:stop], quat[start:stop]
            block[:, 5:8], block[:, 8] = est.omega[start:stop], est.flags[start:stop]
            block[:, 9] = est.iterations[start:stop]
            f.write((row * len(block)) % tuple(block.ravel().tolist()))
    return path


def time_digits(t: Array) -> int:
    """The significant digits that write every time of ``t`` (s) to the µs: 9 (all a log on a clock from
    its start needs, up to 1000 s) or more, up to 17 (a double's). A log whose clock is Unix time (1.7e9 s:
    a re-saved export, the project's CSV with epoch ``t_s``) had its step times rounded to 10 s by 9
    digits, hundreds of steps sharing one time."""
    finite = np.abs(t[np.isfinite(t)])
    largest = float(finite.max()) if finite.size else 0.0
    whole = math.floor(math.log10(largest)) + 1 if largest >= 1.0 else 0  # digits before the point
    return max(9, min(17, whole + 6))


_WRITE_ROWS = 65536
"""Estimate rows formatted at a time (bounds the text and the Python numbers held to a few tens of MB)."""


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
        "sensors": [k.label for k in result.log.kinds],
        "heading": "not observed (no magnetometer): the gyroscope's integral, drifting"
        if result.log.six_axis
        else "observed (magnetometer)",
        "warnings": result.warnings,
        "segments": result.segments,
        "samples": result.samples_read,
        "steps": len(result.estimates),
        "merge": {
            "driver": stats.driver.label if stats.driver is not None else None,
            "accepted": stats.accepted,
            "dropped_nan": stats.nan,
            "dropped_duplicate": stats.duplicate,
            "dropped_out_of_order": stats.out_of_order,
            "dropped_out_of_range": result.out_of_range,
            "dropped_skipped_part": result.skipped_parts,
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
        "rate_drops": {drop.kind.label: drop.as_dict() for drop in result.rate_drops},
        "rest_s": round(_flagged_time(result.estimates, StepFlag.REST), 4),
        "gyro_bias_final_rad_s": None if result.gyro_bias is None else list(result.gyro_bias),
        "rmse_deg": None if result.comparison is None else asdict(result.comparison.rmse),
        "rate_rmse_rad_s": None if result.comparison is None else result.comparison.rate_rmse,
        "files": {k: str(v) for k, v in result.files.items()},
    }
    path.write_text(strict_json(summary, indent=2) + "\n", encoding="utf-8")  # a figure not scored: null
    return path
