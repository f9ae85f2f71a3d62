"""Phone sensor data as the whole host sees it: one sample, a columnar stream, a recorded log, merged steps.

Units and frames (the paper's, = Android's sensor frame): body axes x = screen right, y = screen up,
z = out of the screen. Accelerometer: specific force in m/s², gravity *included* (a phone lying still on
a table reads about +9.81 on z). Gyroscope: body angular rate in rad/s. Magnetometer: field in µT.
Times are seconds on the log's or the source's own clock.

Two shapes of the same data:
- live (samples arrive one by one): :class:`SensorSample` in, :class:`MergedStep` out of the merger;
- batch (a recorded log, 720k samples): :class:`SensorStream` columns in, :class:`MergedSteps` out.
Both carry the same information, and the merger produces identical numbers through either path.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.errors import InputFormatError

Array = NDArray[np.float64]


class SensorKind(enum.IntEnum):
    """The three phone sensors; the value is the column of per-kind arrays (e.g. ``MergedSteps.age``)."""

    GYR = 0
    ACC = 1
    MAG = 2

    @property
    def unit(self) -> str:
        return _UNITS[self]

    @property
    def label(self) -> str:
        """Lower-case name used in CSV headers and reports (``gyr``, ``acc``, ``mag``)."""
        return self.name.lower()


_UNITS = {SensorKind.GYR: "rad/s", SensorKind.ACC: "m/s^2", SensorKind.MAG: "uT"}
KINDS: tuple[SensorKind, ...] = (SensorKind.GYR, SensorKind.ACC, SensorKind.MAG)
MAX_PAUSE_S = 1.0
"""s: a pause of every sensor longer than this is never integrated across — the estimate starts afresh
after it, from the measurements, as at the start (the live host: :mod:`hil.runtime.phone_clock`; a replay
splits the log there: :mod:`hil.logs.replay`). Across a longer pause the gyro's two readings at its ends
are all there is of the motion between them: a step that spans it invents a rotation, and a heading
wrong by more than ~90° then returns only slowly (the magnetic potential's torque goes like the sine of
its error). Measured on the shared recordings with a 3 s pause cut in (docs/estimator.md)."""
REQUIRED: tuple[SensorKind, ...] = (SensorKind.GYR, SensorKind.ACC)
"""Sensors every log must have; the magnetometer is optional (a 6-axis log)."""


class StepFlag(enum.IntFlag):
    """Per-step conditions, set by the merger and the estimator; never silent, always counted."""

    NONE = 0
    GYR_STALE = 1 << 0  # no usable gyroscope sample (never seen, NaN-only, or older than the stale limit)
    ACC_STALE = 1 << 1
    MAG_STALE = 1 << 2
    GAP = 1 << 3  # the step is longer than the merge policy's gap limit (the driver sensor skipped)
    FAILOVER = 1 << 4  # stepped on another sensor's sample because the driving sensor went stale
    DEGENERATE = 1 << 5  # gravity and magnetic field directions (nearly) parallel: only one used
    NEWTON_FAILED = 1 << 6  # the implicit step did not meet its tolerance within the iteration cap
    SUBSTEPPED = 1 << 7  # a long step was split into sub-steps (estimator stability limit)
    MAG_DISTURBED = 1 << 8  # magnetometer rejected: field norm or dip off its reference (disturbance)
    REST = 1 << 9  # the phone is at rest (gyro and accelerometer steady): the gyro bias is measured

    @staticmethod
    def stale(kind: SensorKind) -> StepFlag:
        return StepFlag(1 << int(kind))


@dataclass(frozen=True, slots=True)
class SensorSample:
    """One reading: ``t_s`` seconds, ``xyz`` in the kind's unit, body frame."""

    t_s: float
    kind: SensorKind
    xyz: tuple[float, float, float]


@dataclass(frozen=True)
class SensorStream:
    """All readings of one sensor, columnar: ``t`` (N,) s, ``xyz`` (N, 3) in ``kind.unit``, body frame.

    Rows are kept as recorded (order, duplicates, NaNs): cleaning them is the merger's job, counted there.
    """

    kind: SensorKind
    t: Array
    xyz: Array

    def __post_init__(self) -> None:
        t = np.ascontiguousarray(self.t, dtype=float).reshape(-1)
        xyz = np.ascontiguousarray(self.xyz, dtype=float)
        if xyz.ndim != 2 or xyz.shape != (t.shape[0], 3):
            raise ValueError(
                f"{self.kind.name} stream: xyz has shape {xyz.shape}, expected ({t.shape[0]}, 3)"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "xyz", xyz)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @classmethod
    def from_samples(cls, kind: SensorKind, samples: list[SensorSample]) -> SensorStream:
        return cls(
            kind,
            np.array([s.t_s for s in samples], dtype=float),
            np.array([s.xyz for s in samples], dtype=float).reshape(-1, 3),
        )

    def samples(self) -> Iterator[SensorSample]:
        for t, (x, y, z) in zip(self.t.tolist(), self.xyz.tolist(), strict=True):
            yield SensorSample(t, self.kind, (x, y, z))

    def median_period(self) -> float:
        """Median positive interval between timestamps (s); inf for fewer than two distinct times."""
        dt = np.diff(self.t[np.isfinite(self.t)])
        dt = dt[dt > 0]
        return float(np.median(dt)) if dt.size else math.inf

    def shifted(self, dt: float) -> SensorStream:
        return SensorStream(self.kind, self.t + dt, self.xyz)

    def window(self, t0: float, t1: float) -> SensorStream:
        keep = (self.t >= t0) & (self.t <= t1)
        return SensorStream(self.kind, self.t[keep], self.xyz[keep])


@dataclass(frozen=True)
class Truth:
    """Ground-truth attitude: ``t`` (N,) s on the log's sensor clock, ``R`` (N, 3, 3) body → ENU, and
    ``evaluate`` (N,) bool: the samples a benchmark's metric is computed on (its own exclusions applied)."""

    t: Array
    R: Array
    evaluate: Array | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float).reshape(-1)
        r = np.asarray(self.R, dtype=float)
        if r.shape != (t.shape[0], 3, 3):
            raise ValueError(f"truth: R has shape {r.shape}, expected ({t.shape[0]}, 3, 3)")
        ev = np.ones(t.shape[0], bool) if self.evaluate is None else np.asarray(self.evaluate, bool)
        if ev.shape != t.shape:
            raise ValueError(f"truth: evaluate mask has shape {ev.shape}, expected {t.shape}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "R", r)
        object.__setattr__(self, "evaluate", ev)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def window(self, t0: float, t1: float) -> Truth:
        keep = (self.t >= t0) & (self.t <= t1)
        assert self.evaluate is not None
        return Truth(self.t[keep], self.R[keep], self.evaluate[keep])


@dataclass(frozen=True)
class SensorLog:
    """A recorded (or simulated) session: per-sensor streams, optional ground truth, where it came from.

    ``dropped`` counts rows a reader discarded (e.g. ``{"acc: NaN": 3}``) so nothing is lost silently;
    ``notes`` records what the reader did to normalise units, frames and clocks.

    The gyroscope and accelerometer are required; the magnetometer is not: a recording without one
    (:attr:`six_axis`) observes inclination from gravity but not heading, which only the gyroscope
    carries (drifting).
    """

    streams: Mapping[SensorKind, SensorStream]
    source: str
    format: str
    truth: Truth | None = None
    notes: tuple[str, ...] = ()
    dropped: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        missing = [k.name for k in REQUIRED if k not in self.streams or len(self.streams[k]) == 0]
        if missing:
            raise InputFormatError(f"log has no {', '.join(missing)} samples", self.source)
        if SensorKind.MAG in self.streams and len(self.streams[SensorKind.MAG]) == 0:
            raise InputFormatError("log has an empty MAG stream (leave it out for a 6-axis log)", self.source)

    @property
    def six_axis(self) -> bool:
        """No magnetometer: heading is not observed (the gyroscope alone carries it, drifting)."""
        return SensorKind.MAG not in self.streams

    @property
    def kinds(self) -> tuple[SensorKind, ...]:
        """The sensors this log has, in :data:`KINDS` order."""
        return tuple(k for k in KINDS if k in self.streams)

    @property
    def n_samples(self) -> int:
        return sum(len(s) for s in self.streams.values())

    @property
    def start(self) -> float:
        """The time every sensor has spoken by (s): the latest first finite timestamp. A sensor with no
        finite timestamp (every one NaN or ±inf: a clock offset that overflowed, say) is an
        :class:`InputFormatError` naming the log: a log's span is no number then (it crashed the still
        window's search)."""
        return max(float(np.min(self._finite_times(k))) for k in self.streams)

    @property
    def end(self) -> float:
        """The last finite timestamp of any sensor (s); an :class:`InputFormatError` as :attr:`start`."""
        return max(float(np.max(self._finite_times(k))) for k in self.streams)

    def _finite_times(self, kind: SensorKind) -> NDArray[np.float64]:
        t = self.streams[kind].t
        finite = t[np.isfinite(t)]
        if not finite.size:
            raise InputFormatError(
                f"no {kind.name} sample has a finite time ({len(t)} samples: NaN or infinite)", self.source
            )
        return finite

    def window(self, t0: float, t1: float) -> SensorLog:
        """The part of the log between ``t0`` and ``t1`` (s, inclusive), truth included."""
        return SensorLog(
            {k: s.window(t0, t1) for k, s in self.streams.items()},
            f"{self.source}[{t0:g}:{t1:g}]",
            self.format,
            None if self.truth is None else self.truth.window(t0, t1),
            self.notes,
            self.dropped,
        )


@dataclass(frozen=True, slots=True)
class MergedStep:
    """One filter step (live path). ``h`` s since the previous step (0 for the first); a sensor's value is
    None when it is not usable (its stale flag is set); ``age`` s since each held sample was taken (inf if
    none yet), in :data:`KINDS` order; ``fresh`` true where the sample is new since the previous step."""

    t: float
    h: float
    gyr: tuple[float, float, float] | None
    acc: tuple[float, float, float] | None
    mag: tuple[float, float, float] | None
    age: tuple[float, float, float]
    fresh: tuple[bool, bool, bool]
    flags: StepFlag

    def value(self, kind: SensorKind) -> tuple[float, float, float] | None:
        return (self.gyr, self.acc, self.mag)[kind]


@dataclass(frozen=True)
class MergedSteps:
    """Filter steps of a whole log (batch path), columnar, N steps. ``gyr``/``acc``/``mag`` (N, 3) hold
    the held sample, NaN rows where the sensor is not usable; ``age`` (N, 3) s and ``fresh`` (N, 3) bool in
    :data:`KINDS` order; ``flags`` (N,) :class:`StepFlag` bits. ``h[0] = 0``."""

    t: Array
    gyr: Array
    acc: Array
    mag: Array
    age: Array
    fresh: NDArray[np.bool_]
    flags: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def h(self) -> Array:
        return np.diff(self.t, prepend=self.t[:1]) if len(self) else np.zeros(0)

    def value(self, kind: SensorKind) -> Array:
        return (self.gyr, self.acc, self.mag)[kind]

    def valid(self, kind: SensorKind) -> NDArray[np.bool_]:
        return np.asarray((self.flags & int(StepFlag.stale(kind))) == 0)

    def __getitem__(self, i: int) -> MergedStep:
        def vec(a: Array) -> tuple[float, float, float] | None:
            x, y, z = a[i].tolist()
            return None if math.isnan(x) else (x, y, z)

        a0, a1, a2 = self.age[i].tolist()
        f0, f1, f2 = (bool(v) for v in self.fresh[i])
        return MergedStep(
            float(self.t[i]),
            float(self.t[i] - self.t[i - 1]) if i > 0 else 0.0,
            vec(self.gyr),
            vec(self.acc),
            vec(self.mag),
            (a0, a1, a2),
            (f0, f1, f2),
            StepFlag(int(self.flags[i])),
        )

    def __iter__(self) -> Iterator[MergedStep]:
        return (self[i] for i in range(len(self)))

    def rows(self, start: int, stop: int | None = None) -> MergedSteps:
        """Steps ``start:stop`` (views, not copies)."""
        s = slice(start, stop)
        return MergedSteps(
            self.t[s], self.gyr[s], self.acc[s], self.mag[s], self.age[s], self.fresh[s], self.flags[s]
        )

    @classmethod
    def from_steps(cls, steps: list[MergedStep]) -> MergedSteps:
        def col(kind: SensorKind) -> Array:
            nan3 = (math.nan, math.nan, math.nan)
            return np.array([s.value(kind) or nan3 for s in steps], dtype=float).reshape(-1, 3)

        return cls(
            np.array([s.t for s in steps], dtype=float),
            col(SensorKind.GYR),
            col(SensorKind.ACC),
            col(SensorKind.MAG),
            np.array([s.age for s in steps], dtype=float).reshape(-1, 3),
            np.array([s.fresh for s in steps], dtype=bool).reshape(-1, 3),
            np.array([int(s.flags) for s in steps], dtype=np.int64),
        )


def as_vec3(v: ArrayLike | None) -> tuple[float, float, float] | None:
    """A 3-vector as floats, or None if absent or not all finite (the estimator's 'not usable')."""
    if v is None:
        return None
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"expected a 3-vector, got shape {a.shape}")
    x, y, z = a.tolist()
    return (x, y, z) if math.isfinite(x + y + z) else None


def flagged_intervals(t: ArrayLike, flags: ArrayLike, flag: StepFlag) -> list[tuple[float, float]]:
    """The ``(start, end)`` times (s) of every run of consecutive steps carrying ``flag``: e.g. each
    interval in which the magnetometer was left out as disturbed. ``t`` (N,) step times, ``flags`` (N,)."""
    on = (np.asarray(flags, dtype=np.int64) & int(flag)) != 0
    t = np.asarray(t, dtype=float)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(np.int8), [0]])))
    return [(float(t[a]), float(t[b - 1])) for a, b in zip(edges[::2], edges[1::2], strict=True)]
