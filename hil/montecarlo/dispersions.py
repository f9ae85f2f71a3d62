"""Dispersions: which parameters of a scenario vary across a Monte Carlo campaign, and how.

A dispersion file is TOML; every table and key is optional, and an unknown table, parameter or
distribution key is a :class:`ConfigError` naming the file and the dotted key (a typo must never become
"not dispersed"). Each parameter is either a number (a fixed value replacing the scenario's) or an inline
table with a distribution::

    { dist = "normal", sigma = 0.05 }                  # mean: the scenario's value unless given
    { dist = "normal", mean = 1.0, sigma = 0.05 }
    { dist = "normal", relative_sigma = 0.2, low = 0 } # σ = 0.2 × |mean|; optional low/high clip the draw
    { dist = "uniform", low = 0.0, high = 1e-3 }
    { dist = "choice", values = [100, 200, 400], weights = [1, 2, 1] }

Parameters (``[table] key``; "per unit" and "per axis" draw each element independently):

============================================  =====================================================
``spacecraft.inertia_scale``     (per axis)   factor on each diagonal element of the bus inertia
``spacecraft.inertia_offdiag``   (xy, xz, yz) products of inertia added, fraction of the mean moment
``spacecraft.gimbal_misalignment_rad`` (unit) gimbal axis (and its spin axis) tilted by this angle
                                              about a random direction perpendicular to it
``spacecraft.rotor_offset_m``    (per unit)   rotor offset σ along the gimbal axis (m)
``sensors.{gyr,acc,mag}.{noise,bias,rate_hz,jitter_s}``  the phone's sensor (σ of noise and of the
                                              per-run bias, rate, timestamp jitter), as in scenarios
``initial.angle_deg``                         start attitude turned by this angle about a random axis
``manoeuvre.angle_deg``                       slew angle (mean: the scenario's)
``manoeuvre.axis_tilt_deg``                   slew axis tilted by this angle in a random direction
``link.outages_per_minute``                   rate of link outages (Poisson) over the run: the
                                              board's first warm-up + duration seconds (its clock)
``link.outage_duration_s``                    each outage's duration (required with a rate)
============================================  =====================================================

A run's parameters are a pure function of the campaign seed and the run index: every parameter draws
from its own stream ``numpy.random.default_rng([seed, index, crc32(key)])``, so run 17 of seed 3 is the
same run on any machine and in any order, and adding a dispersion to a file leaves the draws of the others
unchanged (common random numbers between campaign variants).

Every parameter has bounds on its size (:data:`BOUNDS`: a sensor rate at most 1 kHz, an angle at most a
turn, ...): a file that asks for more is refused naming the file and key, and draws are clipped into them;
so is a normal whose σ is wider than the whole range (every draw would land on its ends), or whose own
``low``/``high`` would take most draws (a mean outside them, a σ wider than them). Each drawn link
outage lasts :data:`OUTAGE_S` (1 ms..60 s), the board's refusal of a stall of no time never a run's fate.
Within them, values are not checked at draw time: a drawn value the model refuses (a negative noise, an
inertia that is not positive definite) makes that run fail with an error naming the parameter, recorded
with the run. The file itself is read bounded (:mod:`hil.files.bounded`: at most 16 MiB, nested at most
32 deep).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil import so3
from hil.files.bounded import MAX_DOCUMENT_BYTES, load_toml
from hil.numbers import is_finite_number
from hil.runtime.invariants import InjectedFault
from hil.scenario import Scenario
from hil.scenario.paths import FIXTURES, read_text, resolve_named_file
from hil.scenario.reader import MAX_SLEW_DEG, MIN_NEEDED_SENSOR_RATE_HZ, NEEDED_SENSORS
from protocol.errors import ConfigError

from .fault_plan import (
    FaultSpec,
    board_of,
    check_board,
    check_rates,
    draw_faults,
    fixed_values,
    parse_faults,
)
from .fault_plan import describe as describe_faults

Array = NDArray[np.float64]

DISPERSION_DIR = FIXTURES / "dispersions"
DEFAULT_DISPERSIONS = DISPERSION_DIR / "default.toml"
LINK_RANGES = {"link.outages_per_minute": (0.0, 600.0), "link.outage_duration_s": (0.0, 60.0)}
"""What link outages a file may ask for: up to ten a second, each up to a minute (a rate's draws are
clipped into it, so a run's outage list stays bounded: at most ~10 per second of run)."""
OUTAGE_S = (1e-3, LINK_RANGES["link.outage_duration_s"][1])
"""What one drawn outage may last (s): a normal's tail is clipped into it (an outage of 1e160 s, or of a
negative time, is no stall the board can be given: every such run failed with its option refused)."""
MAX_OUTAGES = 1000
"""Link outages in one run, at most: each is a ``--stall`` of the board and a cell of ``runs.csv``. A rate
whose Poisson count over the run could pass it is refused as the file is read (:func:`_check_outage_count`:
600 a minute over a day-long run drew 860 000 outages a run, a 14 MB ``link.outage_list`` cell and as many
board options); a draw past it all the same (a normal rate's far tail) is clipped to it."""
POSITIVE = frozenset({"link.outage_duration_s"})
"""Parameters whose values as written (a fixed value, a choice's values: :func:`~.fault_plan.fixed_values`)
must be positive: an outage of no time is none, so a file asking for it is refused — not every run
failing, nor a 1 ms outage flown in its place. A normal's draws, its mean among them, are clipped into
:data:`OUTAGE_S` as its tail is."""
BOUNDS: dict[str, tuple[float, float]] = {
    "spacecraft.inertia_scale": (-100.0, 100.0),
    "spacecraft.inertia_offdiag": (-1.0, 1.0),
    "spacecraft.gimbal_misalignment_rad": (-math.pi, math.pi),
    "spacecraft.rotor_offset_m": (-0.1, 0.1),
    "sensors.*.noise": (-1e3, 1e3),
    "sensors.*.bias": (-1e3, 1e3),
    "sensors.*.rate_hz": (-1e3, 1e3),
    **{f"sensors.{kind}.rate_hz": (MIN_NEEDED_SENSOR_RATE_HZ, 1e3) for kind in NEEDED_SENSORS},
    "sensors.*.jitter_s": (-0.1, 0.1),
    "initial.angle_deg": (-360.0, 360.0),
    "manoeuvre.angle_deg": (-MAX_SLEW_DEG, MAX_SLEW_DEG),  # flown the short way: 270 would be 90 back
    "manoeuvre.axis_tilt_deg": (-180.0, 180.0),
    **LINK_RANGES,
}
"""The most a dispersion may ask of each parameter (``sensors.*`` for each sensor), as the scenario's own
bounds (:data:`hil.scenario.reader.RANGES`) have it: a value beyond them (a phone sampling at 10⁹ Hz) makes
a run that cannot end or cannot be simulated. A fixed value, a uniform's ends, a choice's values and a
normal's mean and clip bounds must lie within them (a :class:`ConfigError` naming the file and key), and
every draw is clipped into them (a normal's tail). Within them, a value the model refuses (a negative noise)
is the run's failure, recorded with it, not the file's: the bounds are about size, not sign — but for the
gyroscope's and accelerometer's rates, which the host cannot steer below
(:data:`hil.scenario.reader.MIN_NEEDED_SENSOR_RATE_HZ`, as a scenario: every run of a draw below it ended
"lost: phone"), so a file asking for less is refused and a normal's tail clipped up to it."""


# --------------------------------------------------------------------------- distributions
@dataclass(frozen=True)
class Fixed:
    """A value replacing the scenario's in every run (not a column of the results)."""

    value: float

    def sample(self, rng: np.random.Generator, nominal: Array) -> Array:
        return np.full(nominal.shape, self.value)


@dataclass(frozen=True)
class Normal:
    """Normal about ``mean`` (None: the scenario's value) with ``sigma``, or ``relative_sigma`` × |mean|;
    draws outside ``[low, high]`` (when given) are clipped to it."""

    sigma: float | None = None
    relative_sigma: float | None = None
    mean: float | None = None
    low: float | None = None
    high: float | None = None

    def sample(self, rng: np.random.Generator, nominal: Array) -> Array:
        mean = nominal if self.mean is None else np.full(nominal.shape, self.mean)
        sigma = self.sigma if self.sigma is not None else float(self.relative_sigma or 0.0) * np.abs(mean)
        x = mean + sigma * rng.standard_normal(nominal.shape)
        return np.clip(x, *self.clip_bounds)

    @property
    def clip_bounds(self) -> tuple[float, float]:
        """``[low, high]`` with a bound not given as ∓inf (the parameter's unit)."""
        return (-math.inf if self.low is None else self.low, math.inf if self.high is None else self.high)

    def check_clip(self, nominal: Array, where: str, nominal_is: str = "the scenario's value") -> None:
        """Refuse clip bounds that would take most of the draws: a ``ConfigError`` at ``where.low`` /
        ``where.high`` / ``where.sigma``. A mean (``mean``, else every element of ``nominal``, described as
        ``nominal_is``) outside ``[low, high]`` has more than half its draws clipped onto the bound, and
        all of them when it lies many σ out (``sigma = 0.01, low = 2`` about an inertia scale of 1 flew
        every run at exactly 2: a dispersion asked for and a fixed value flown); a σ wider than
        ``high - low`` puts most draws on the two ends (as :func:`_check_spread` for a whole range)."""
        if self.low is None and self.high is None:
            return
        lo, hi = self.clip_bounds
        means = np.ravel(nominal) if self.mean is None else np.array([self.mean])
        outside = [float(m) for m in means if not lo <= m <= hi]
        if outside:
            said = f"the mean {outside[0]:g}" if self.mean is not None else f"{nominal_is} ({outside[0]:g})"
            bound, name = (lo, "low") if outside[0] < lo else (hi, "high")
            raise ConfigError(
                f"{said} lies outside the clip bounds {lo:g}..{hi:g}: most draws (far out, every one) would "
                f"be clipped to {bound:g}, a fixed value and no dispersion; give a mean within them",
                f"{where}.{name}",
            )
        if self.sigma is not None:
            sigma, name = self.sigma, "sigma"
        else:
            sigma, name = float(self.relative_sigma or 0.0) * float(np.max(np.abs(means))), "relative_sigma"
        if not sigma <= hi - lo:
            raise ConfigError(
                f"a spread of {sigma:g} is wider than the clip bounds {lo:g}..{hi:g}: most draws would be "
                "clipped to their ends",
                f"{where}.{name}",
            )


@dataclass(frozen=True)
class Uniform:
    low: float
    high: float

    def sample(self, rng: np.random.Generator, nominal: Array) -> Array:
        return rng.uniform(self.low, self.high, nominal.shape)


@dataclass(frozen=True)
class Choice:
    """One of ``values`` (with ``weights``, normalised; None: equally likely)."""

    values: tuple[float, ...]
    weights: tuple[float, ...] | None = None

    def sample(self, rng: np.random.Generator, nominal: Array) -> Array:
        p = None if self.weights is None else np.asarray(self.weights) / sum(self.weights)
        return rng.choice(np.asarray(self.values, dtype=float), size=nominal.shape, p=p)


Distribution = Fixed | Normal | Uniform | Choice

_DIST_KEYS: dict[str, tuple[frozenset[str], frozenset[str]]] = {  # required, optional
    "normal": (frozenset(), frozenset({"mean", "sigma", "relative_sigma", "low", "high"})),
    "uniform": (frozenset({"low", "high"}), frozenset()),
    "choice": (frozenset({"values"}), frozenset({"weights"})),
}


# --------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class Parameter:
    """A dispersible parameter: its dotted ``key``, the labels of its elements (column suffixes; () for a
    scalar) and its nominal values (shape (len(labels),) or (1,)) for a scenario."""

    key: str
    labels: Callable[[Scenario], tuple[str, ...]]
    nominal: Callable[[Scenario], Array]

    def columns(self, scenario: Scenario) -> list[str]:
        labels = self.labels(scenario)
        return [f"{self.key}.{label}" for label in labels] if labels else [self.key]


def _units(sc: Scenario) -> tuple[str, ...]:
    return tuple(str(i) for i in range(sc.n_units))


def _scalar(value: Callable[[Scenario], float]) -> Callable[[Scenario], Array]:
    return lambda sc: np.array([float(value(sc))])


def slew_angle_deg(sc: Scenario) -> float:
    """The scenario's slew angle (deg), from its start and target attitudes."""
    return math.degrees(so3.principal_angle(np.asarray(sc.slew.R0).T @ np.asarray(sc.slew.R_target)))


SENSOR_KINDS = ("gyr", "acc", "mag")
SENSOR_FIELDS = ("noise", "bias", "rate_hz", "jitter_s")


def _sensor(kind: str, name: str) -> Parameter:
    return Parameter(
        f"sensors.{kind}.{name}", lambda sc: (), _scalar(lambda sc: getattr(getattr(sc.phone, kind), name))
    )


PARAMETERS: tuple[Parameter, ...] = (
    Parameter("spacecraft.inertia_scale", lambda sc: ("x", "y", "z"), lambda sc: np.ones(3)),
    Parameter("spacecraft.inertia_offdiag", lambda sc: ("xy", "xz", "yz"), lambda sc: np.zeros(3)),
    Parameter("spacecraft.gimbal_misalignment_rad", _units, lambda sc: np.zeros(sc.n_units)),
    Parameter(
        "spacecraft.rotor_offset_m",
        _units,
        lambda sc: np.array([u.rotor_offset_m for u in sc.spacecraft.units]),
    ),
    *(_sensor(kind, name) for kind in SENSOR_KINDS for name in SENSOR_FIELDS),
    Parameter("initial.angle_deg", lambda sc: (), lambda sc: np.zeros(1)),
    Parameter("manoeuvre.angle_deg", lambda sc: (), _scalar(slew_angle_deg)),
    Parameter("manoeuvre.axis_tilt_deg", lambda sc: (), lambda sc: np.zeros(1)),
    Parameter("link.outages_per_minute", lambda sc: (), lambda sc: np.zeros(1)),
    Parameter("link.outage_duration_s", lambda sc: (), lambda sc: np.zeros(1)),
)
"""Every dispersible parameter, in the canonical order of the results' columns."""

_BY_KEY = {p.key: p for p in PARAMETERS}
FAULT_COLUMNS = ("faults.n", "faults.list")
"""Columns describing a run's drawn faults (with a ``[faults]`` section): how many, and each as
``kind@t param=value`` (:mod:`.fault_plan`)."""
LINK_COLUMNS = ("link.outages", "link.outage_s", "link.outage_list")
"""Columns describing a run's drawn outages (with link dispersions): count, total seconds, and the list
``start:duration;...`` (seconds on the board's clock, from its start: firmware-sim's ``--stall``)."""


# --------------------------------------------------------------------------- a campaign's dispersions
@dataclass(frozen=True)
class Dispersions:
    """A dispersion file bound to the scenario it disperses (nominal values, unit count, run duration).
    ``entries``: (parameter, distribution) in canonical order; ``text`` the file as read; ``where`` its
    name for messages."""

    scenario: Scenario
    entries: tuple[tuple[Parameter, Distribution], ...]
    text: str = ""
    where: str = "<dispersions>"
    faults: FaultSpec | None = None

    def get(self, key: str) -> Distribution | None:
        return next((d for p, d in self.entries if p.key == key), None)

    @property
    def has_link(self) -> bool:
        return self.get("link.outages_per_minute") is not None

    def columns(self) -> list[str]:
        """The results' parameter columns: every element of every drawn (not fixed) parameter, then the
        link outages' summary when outages are dispersed."""
        cols: list[str] = []
        for param, dist in self.entries:
            if not isinstance(dist, Fixed) and param.key != "link.outage_duration_s":
                cols += param.columns(self.scenario)
        cols += list(LINK_COLUMNS) if self.has_link else []
        return cols + (list(FAULT_COLUMNS) if self.faults is not None else [])


@dataclass(frozen=True)
class RunParams:
    """One run's draws. ``values``: parameter key → drawn values (shape as the parameter's nominal);
    ``directions``: the random directions some parameters turn about (``initial.angle_deg``: a unit axis
    (3,); ``manoeuvre.axis_tilt_deg`` and ``spacecraft.gimbal_misalignment_rad``: azimuths (rad) of the
    tilt about the tilted axis, (1,) or per unit); ``outages``: ``(start_s, duration_s)`` on the board's
    clock (from its start, as firmware-sim's ``--stall AT:DURATION``); ``phone_seed``: the run's
    sensor-noise stream; ``columns``: the values flattened for the results (column name → value);
    ``faults``: the faults drawn for the run (:mod:`.fault_plan`; None: the file has no ``[faults]``)."""

    index: int
    seed: int
    phone_seed: int
    values: Mapping[str, Array]
    directions: Mapping[str, Array]
    outages: tuple[tuple[float, float], ...]
    columns: Mapping[str, float | int | str]
    faults: tuple[InjectedFault, ...] | None = None


def _stream(seed: int, index: int, key: str) -> np.random.Generator:
    return np.random.default_rng([seed, index, zlib.crc32(key.encode())])


def draw(dispersions: Dispersions, seed: int, run_index: int) -> RunParams:
    """Run ``run_index``'s parameters: a pure function of ``(seed, run_index)`` (see the module docstring)."""
    if run_index < 0 or seed < 0:
        raise ConfigError(f"seed and run index must be non-negative, got {seed}, {run_index}", "draw")
    sc = dispersions.scenario
    values: dict[str, Array] = {}
    directions: dict[str, Array] = {}
    columns: dict[str, float | int | str] = {}
    outages: tuple[tuple[float, float], ...] = ()
    for param, dist in dispersions.entries:
        rng = _stream(seed, run_index, param.key)
        if param.key == "link.outage_duration_s":
            continue
        drawn = np.clip(dist.sample(rng, param.nominal(sc)), *bounds_of(param.key))
        values[param.key] = drawn
        if param.key == "initial.angle_deg":
            directions[param.key] = _isotropic(rng)
        elif param.key in ("manoeuvre.axis_tilt_deg", "spacecraft.gimbal_misalignment_rad"):
            directions[param.key] = rng.uniform(0.0, 2.0 * math.pi, drawn.shape)
        elif param.key == "link.outages_per_minute":
            duration = dispersions.get("link.outage_duration_s")
            assert duration is not None, "checked when the file was read"
            outages = _outages(rng, float(drawn[0]), duration, outage_window_s(sc))
        if not isinstance(dist, Fixed):
            columns.update(zip(param.columns(sc), (float(v) for v in drawn), strict=True))
    if dispersions.has_link:
        columns["link.outages"] = len(outages)
        columns["link.outage_s"] = float(sum(d for _, d in outages))
        columns["link.outage_list"] = ";".join(f"{a:.3f}:{d:.3f}" for a, d in outages)
    faults = None
    if dispersions.faults is not None:
        faults = draw_faults(dispersions.faults, sc, seed, run_index)
        columns["faults.n"] = len(faults)
        columns["faults.list"] = describe_faults(faults)
    phone_seed = int(_stream(seed, run_index, "phone").integers(2**31))
    return RunParams(run_index, seed, phone_seed, values, directions, outages, columns, faults)


def outage_window_s(scenario: Scenario) -> float:
    """The span (s of board time from its start) link outages are drawn over: the warm-up and the run's
    duration (the board's clock also covers the connection and the rotors' spin-up, ~0.7 s at 1U scale,
    so the window ends a little before the run does)."""
    return scenario.loop.warmup_s + scenario.slew.duration_s


def _isotropic(rng: np.random.Generator) -> Array:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def _outages(
    rng: np.random.Generator, per_minute: float, duration: Distribution, run_s: float
) -> tuple[tuple[float, float], ...]:
    """A Poisson process of ``per_minute`` outages over ``run_s`` seconds, each lasting a draw of
    ``duration``; the rate is clipped into :data:`LINK_RANGES` (a normal's tail) and the count to
    :data:`MAX_OUTAGES`, so a run's outages stay bounded whatever its length."""
    lo, hi = LINK_RANGES["link.outages_per_minute"]
    count = min(int(rng.poisson(min(max(per_minute, lo), hi) * run_s / 60.0)), MAX_OUTAGES)
    starts = np.sort(rng.uniform(0.0, run_s, count))
    lengths = np.clip(duration.sample(rng, np.zeros(count)), *OUTAGE_S)
    return tuple((float(a), float(d)) for a, d in zip(starts, lengths, strict=True))


# --------------------------------------------------------------------------- reading files
def resolve_dispersions_path(name_or_path: str | Path | None) -> Path:
    """A path as given (a file, or a pipe: ``--dispersions <(…)``), ``default`` (or None) for the shipped
    default, or a shipped file by name; as a scenario's (:func:`~hil.scenario.paths.resolve_named_file`)."""
    if name_or_path is None:
        return DEFAULT_DISPERSIONS
    return resolve_named_file(name_or_path, DISPERSION_DIR, "dispersion", "dispersions")


def load_dispersions(name_or_path: str | Path | None, scenario: Scenario) -> Dispersions:
    """Read a dispersion file (see :func:`resolve_dispersions_path`) for ``scenario``; errors are
    :class:`ConfigError` naming the file and the dotted key."""
    path = resolve_dispersions_path(name_or_path)
    return parse_dispersions(read_text(path, limit=MAX_DOCUMENT_BYTES), scenario, path.name)


def parse_dispersions(text: str, scenario: Scenario, where: str = "<dispersions>") -> Dispersions:
    """:func:`load_dispersions` on TOML text (``where`` names the source in errors)."""
    doc = load_toml(text, where)
    faults = parse_faults(doc.pop("faults"), where, _distribution) if "faults" in doc else None
    if faults is not None:
        check_board((k.kind for k in faults.kinds), board_of(scenario), where)
        check_rates(faults, scenario, where)
    found: dict[str, Distribution] = {}
    for key, value in _leaves(doc, where):
        if key not in _BY_KEY:
            known = ", ".join(p.key for p in PARAMETERS)
            raise ConfigError(f"unknown parameter; known: {known}", f"{where}: {key}")
        found[key] = _distribution(value, f"{where}: {key}")
    rate, duration = found.get("link.outages_per_minute"), found.get("link.outage_duration_s")
    if (rate is None) != (duration is None):
        missing = "link.outage_duration_s" if duration is None else "link.outages_per_minute"
        raise ConfigError("link outages need both a rate and a duration", f"{where}: {missing}")
    for key, dist in found.items():
        lo, hi = bounds_of(key)
        _check_support(dist, lo, hi, f"{where}: {key}")
        nominal = _BY_KEY[key].nominal(scenario)
        _check_relative(dist, nominal, f"{where}: {key}")
        _check_spread(dist, nominal, hi - lo, f"{where}: {key}")
        if isinstance(dist, Normal):
            dist.check_clip(nominal, f"{where}: {key}")
        not_positive = [v for v in fixed_values(dist, normal=False) if not v > 0] if key in POSITIVE else []
        if not_positive:
            raise ConfigError(f"must be positive, got {not_positive[0]:g}", f"{where}: {key}")
    if rate is not None:
        _check_outage_count(rate, outage_window_s(scenario), f"{where}: link.outages_per_minute")
    entries = tuple((p, found[p.key]) for p in PARAMETERS if p.key in found)
    return Dispersions(scenario, entries, text, where, faults)


def bounds_of(key: str) -> tuple[float, float]:
    """A parameter's :data:`BOUNDS` (its own, else a sensor's by its field)."""
    if key in BOUNDS:
        return BOUNDS[key]
    parts = key.split(".")
    return BOUNDS[f"sensors.*.{parts[2]}" if parts[0] == "sensors" else key]


def _check_support(dist: Distribution, lo: float, hi: float, where: str) -> None:
    """Refuse a distribution that can draw outside ``[lo, hi]`` (a normal's mean and its clip bounds)."""
    if isinstance(dist, Fixed):
        values: tuple[float | None, ...] = (dist.value,)
    elif isinstance(dist, Uniform):
        values = (dist.low, dist.high)
    elif isinstance(dist, Choice):
        values = dist.values
    else:
        values = (dist.mean, dist.low, dist.high)
    bad = [v for v in values if v is not None and not lo <= v <= hi]
    if bad:
        raise ConfigError(f"{bad[0]:g} is outside {lo:g}..{hi:g}", where)


def _check_relative(dist: Distribution, nominal: Array, where: str) -> None:
    """Refuse a normal's ``relative_sigma`` about a mean of 0 (the scenario's value, any element of it, or
    the ``mean`` given): σ = relative_sigma × |mean| is then 0 and every run drew the nominal value, a
    dispersion asked for and never made (products of inertia, a rotor offset of 0)."""
    if not isinstance(dist, Normal) or dist.relative_sigma is None:
        return
    mean = np.abs(nominal) if dist.mean is None else np.array([abs(dist.mean)])
    if mean.size and not np.all(mean > 0):
        said = f"the mean given is {dist.mean:g}" if dist.mean is not None else "the scenario's value is 0"
        if dist.mean is None and not np.all(mean == 0):
            said = "an element of the scenario's value is 0"
        raise ConfigError(
            f"{said}, so relative_sigma × |mean| is 0 and no run would be dispersed; give sigma (an absolute "
            "spread) instead",
            f"{where}.relative_sigma",
        )


def _check_spread(dist: Distribution, nominal: Array, span: float, where: str) -> None:
    """Refuse a normal whose σ (``sigma``, or ``relative_sigma`` × the largest |mean|) is wider than the
    parameter's whole range ``span``: its draws would all be clipped to the range's ends (σ = 1e160 made
    every run ±100 × the inertia), and ``relative_sigma`` × |mean| could overflow to inf."""
    if not isinstance(dist, Normal):
        return
    if dist.sigma is not None:
        sigma, name = dist.sigma, "sigma"
    else:
        mean = abs(dist.mean) if dist.mean is not None else float(np.max(np.abs(nominal), initial=0.0))
        sigma, name = float(dist.relative_sigma or 0.0) * mean, "relative_sigma"
    if not sigma <= span:
        raise ConfigError(
            f"a spread of {sigma:g} is wider than the parameter's whole range ({span:g}): "
            "every draw would be clipped to its ends",
            f"{where}.{name}",
        )


def _check_outage_count(rate: Distribution, window_s: float, where: str) -> None:
    """Refuse a link outage rate (outages a minute) that could draw more than :data:`MAX_OUTAGES` outages
    over ``window_s`` seconds: the rate's largest draw (a fixed value, a uniform's ``high``, a choice's
    largest value, a normal's mean + 5 σ, as clipped into :data:`LINK_RANGES`) gives a Poisson mean ``m``,
    and ``m + 5 √m`` must fit — so an accepted file is never a clipped count, but a run's length (a day) can
    make a rate fine for a minute-long run too many outages to give the board."""
    if isinstance(rate, Fixed):
        largest = rate.value
    elif isinstance(rate, Uniform):
        largest = rate.high
    elif isinstance(rate, Choice):
        largest = max(rate.values)
    else:
        mean = rate.mean if rate.mean is not None else 0.0  # the nominal rate: no outages
        sigma = rate.sigma if rate.sigma is not None else float(rate.relative_sigma or 0.0) * abs(mean)
        largest = min(mean + 5.0 * sigma, rate.clip_bounds[1])
    largest = min(largest, LINK_RANGES["link.outages_per_minute"][1])
    expected = max(largest, 0.0) * window_s / 60.0
    if expected + 5.0 * math.sqrt(expected) > MAX_OUTAGES:
        raise ConfigError(
            f"up to {largest:g} outages a minute over the {window_s:g} s a run's outages are drawn over (its "
            f"warm-up and duration) is ~{expected:.0f} outages a run; a run takes at most {MAX_OUTAGES} "
            f"(about {MAX_OUTAGES * 60.0 / window_s * 0.8:.3g} a minute here): lower the rate",
            where,
        )


def _leaves(node: Mapping[str, Any], where: str, prefix: str = "") -> list[tuple[str, Any]]:
    """(dotted key, value) of every parameter: a number or an inline table with ``dist``."""
    out: list[tuple[str, Any]] = []
    for key, value in node.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict) and "dist" not in value and dotted not in _BY_KEY:
            if not value and dotted not in _TABLES:
                raise ConfigError("unknown table", f"{where}: {dotted}")
            out += _leaves(value, where, dotted + ".")
        else:
            out.append((dotted, value))
    return out


_TABLES = frozenset(
    {"spacecraft", "sensors", "initial", "manoeuvre", "link"} | {f"sensors.{k}" for k in SENSOR_KINDS}
)


def _distribution(value: Any, where: str) -> Distribution:
    if is_finite_number(value):
        return Fixed(float(value))
    if not isinstance(value, dict):
        raise ConfigError(f"must be a number or a distribution table, got {value!r}", where)
    kind = value.get("dist")
    if kind not in _DIST_KEYS:
        raise ConfigError(f"dist must be one of {', '.join(_DIST_KEYS)}; got {kind!r}", f"{where}.dist")
    required, optional = _DIST_KEYS[kind]
    for key in value:
        if key != "dist" and key not in required | optional:
            raise ConfigError(
                f"unknown key for a {kind} distribution; known: {', '.join(sorted(required | optional))}",
                f"{where}.{key}",
            )
    for key in sorted(required - set(value)):
        raise ConfigError(f"required for a {kind} distribution", f"{where}.{key}")
    if kind == "choice":
        return _choice(value, where)
    numbers = {}
    for key in set(value) - {"dist"}:
        if not is_finite_number(value[key]):
            raise ConfigError(f"must be a finite number, got {value[key]!r}", f"{where}.{key}")
        numbers[key] = float(value[key])
    low, high = numbers.get("low"), numbers.get("high")
    if low is not None and high is not None and not low < high:
        raise ConfigError(f"low ({low}) must be below high ({high})", f"{where}.high")
    if kind == "uniform":
        return Uniform(numbers["low"], numbers["high"])
    if ("sigma" in numbers) == ("relative_sigma" in numbers):
        raise ConfigError("give exactly one of sigma and relative_sigma", f"{where}.sigma")
    for key in ("sigma", "relative_sigma"):
        if numbers.get(key, 0.0) < 0:
            raise ConfigError("must not be negative", f"{where}.{key}")
    return Normal(**numbers)


def _choice(value: dict[str, Any], where: str) -> Choice:
    values = value["values"]
    if not isinstance(values, list) or not values or not all(is_finite_number(v) for v in values):
        raise ConfigError(f"must be a non-empty list of numbers, got {values!r}", f"{where}.values")
    weights = value.get("weights")
    if weights is not None and (
        not isinstance(weights, list)
        or len(weights) != len(values)
        or not all(is_finite_number(w) and w >= 0 for w in weights)
        or not 0 < sum(weights) < math.inf
    ):
        raise ConfigError(
            f"must be {len(values)} non-negative numbers, not all zero; got {weights!r}", f"{where}.weights"
        )
    return Choice(
        tuple(float(v) for v in values), None if weights is None else tuple(float(w) for w in weights)
    )
