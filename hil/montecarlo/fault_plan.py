"""The ``[faults]`` section of a dispersion file: which faults a campaign's runs are given, how many, and
when — each at a time drawn **uniformly over the whole run** (handshake, warm-up, spin-up, slew, hold),
never at fixed moments — and how a run's drawn faults reach it: the board's and the world's fault
injection (``emu://`` options, firmware-sim's ``--stall``, ``--unplug``, ...) and the operator's commands
(:class:`hil.runtime.operator.ScheduledOperator`, the path the ground station's take).

Each kind is a table: ``count`` (a whole number, or a distribution rounded to one) or ``per_minute``
(a Poisson rate over the run), and the kind's parameters (a number or a distribution, as for dispersions;
``spoof`` and ``channels`` take strings)::

    [faults]
    hang = { count = 1 }
    unplug = { count = 1, duration_s = { dist = "uniform", low = 0.3, high = 4.0 } }
    stall = { per_minute = 2.0, duration_s = { dist = "uniform", low = 0.05, high = 1.0 } }
    phone_spoof = { count = 2, spoof = ["huge", "nan", "future"] }
    disarm = { count = 1, arm_after_s = { dist = "uniform", low = 1.0, high = 6.0 } }

==============  =====================================  ==================================================
kind            parameters                             what happens
==============  =====================================  ==================================================
``stall``       ``duration_s``                         the link carries nothing (a pulled cable)
``hang``        —                                      the MCU's main loop hangs: a watchdog reset
``brownout``    —                                      the pack collapses for 0.3 s: a brown-out reset
``unplug``      ``duration_s``                         the board's USB cable out: port gone, board off,
                                                       then a power-on boot (a restarted board)
``noise``       ``duration_s``, ``corrupt``            bytes damaged at ``corrupt`` per byte, both ways
``dead_esc``    ``channels`` (rotors, gimbals, any)    one output's ESC or servo dies for good
``phone_gap``   ``duration_s``                         the phone stops streaming, then resumes
``phone_jump``  ``offset_s``                           the phone's clock jumps (negative: back)
``phone_spoof`` ``spoof`` (list of kinds)              hostile readings: huge, nan, saturated, future,
                                                       past, duplicate, burst
``disarm``      ``arm_after_s`` (optional)             the operator's Disarm (and Arm that much later)
``arm``         —                                      the operator's Arm
``abort``       —                                      the operator's abort (the run ends)
``slew``        ``roll_deg``, ``pitch_deg``,           the operator's slew to a new attitude
                ``yaw_deg``
``hold``        —                                      the operator's hold
==============  =====================================  ==================================================

Not every board models every kind: the firmware board (``--board firmware``, the ELF under simavr) has no
``unplug`` (:data:`UNAVAILABLE`). A file that asks one for it is refused when it is read, naming the kind
and the board (:func:`check_board`) — never a run that quietly goes without; ``faults-firmware`` is the
shipped campaign without it.

A run's faults are a pure function of the campaign seed, the run index and the kind (their own random
stream, ``[seed, index, crc32("faults." + kind)]``): adding a kind leaves the others' draws unchanged.
Counts are bounded (:data:`MAX_COUNT` per kind and run, a rate's Poisson draw included) and durations too
(:data:`MIN_DURATION_S`..:data:`MAX_DURATION_S`; a duration of 0 as written — fixed, a choice's value, a
normal of no spread — is refused, not flown as 1 ms). A normal's spread must be some and within its range:
``relative_sigma`` needs a non-zero ``mean`` (a count and a parameter have no nominal value of their own),
a spread wider than the whole range is refused, and so are ``low``/``high`` clip bounds that would take
most of the draws (a mean outside them, or a spread wider than them: ``Normal.check_clip``).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from hil.runtime.invariants import FAULT_KINDS, OPERATOR_KINDS, SPOOF_REASONS, InjectedFault
from hil.runtime.operator import OperatorCommand
from hil.scenario import Scenario
from protocol.errors import ConfigError

MAX_COUNT = 100
"""Faults of one kind in one run, at most (a rate's draw is clipped to it)."""
MAX_DURATION_S = 60.0
"""The longest stall, unplug, noise burst or phone gap a file may ask for (s)."""
MIN_DURATION_S = 1e-3
"""The shortest one a draw is given (s): the board and the world refuse a fault of no time (``--stall
T:0``), so a draw clipped to 0 made its run crash, counted as the run's own violation."""
MAX_JUMP_S = 86_400.0
"""The largest phone clock jump (s, either way): what the world's ``--phone-jump`` takes."""
CHANNEL_SETS = ("rotors", "gimbals", "any")

_PARAMS: dict[str, dict[str, tuple[float, float] | None]] = {
    "stall": {"duration_s": (0.0, MAX_DURATION_S)},
    "hang": {},
    "brownout": {},
    "unplug": {"duration_s": (0.05, MAX_DURATION_S)},
    "noise": {"duration_s": (0.0, MAX_DURATION_S), "corrupt": (0.0, 1.0)},
    "dead_esc": {"channels": None},
    "phone_gap": {"duration_s": (0.0, MAX_DURATION_S)},
    "phone_jump": {"offset_s": (-MAX_JUMP_S, MAX_JUMP_S)},
    "phone_spoof": {"spoof": None},
    "disarm": {"arm_after_s": (0.0, 600.0)},
    "arm": {},
    "abort": {},
    "slew": {"roll_deg": (-180.0, 180.0), "pitch_deg": (-90.0, 90.0), "yaw_deg": (-180.0, 180.0)},
    "hold": {},
}
"""Each kind's parameters and the range a value must lie in (None: a string parameter)."""
_REQUIRED = {
    "stall": ("duration_s",),
    "unplug": ("duration_s",),
    "noise": ("duration_s", "corrupt"),
    "phone_gap": ("duration_s",),
    "phone_jump": ("offset_s",),
}
_DEFAULTS: dict[str, dict[str, Any]] = {
    "slew": {"roll_deg": (-30.0, 30.0), "pitch_deg": (-20.0, 20.0), "yaw_deg": (-60.0, 60.0)},
    "dead_esc": {"channels": "any"},
    "phone_spoof": {"spoof": tuple(SPOOF_REASONS)},
}
"""What a parameter left out means: a range to draw uniformly from, or a value."""
UNAVAILABLE: dict[str, dict[str, str]] = {
    "firmware": {
        "unplug": "a cable unplug is not modelled: the simavr harness has no unpowered MCU that comes back "
        "with a power-on reset",
    },
}
"""The kinds a board cannot be given (board → kind → why); a board not named takes every kind."""


@dataclass(frozen=True)
class KindSpec:
    """One kind's table: how many (``count`` a distribution, or ``per_minute``) and its parameters
    (name → a distribution, or strings)."""

    kind: str
    count: Any | None
    per_minute: float | None
    params: Mapping[str, Any]


@dataclass(frozen=True)
class FaultSpec:
    """The ``[faults]`` section as read."""

    kinds: tuple[KindSpec, ...]


def parse_faults(table: Any, where: str, distribution: Any) -> FaultSpec:
    """The ``[faults]`` table (``distribution`` reads a number-or-distribution value, as dispersions do);
    errors are :class:`ConfigError` naming the file and the dotted key."""
    if not isinstance(table, dict):
        raise ConfigError("must be a table of fault kinds", f"{where}: faults")
    kinds = []
    for kind, spec in table.items():
        at = f"{where}: faults.{kind}"
        if kind not in _PARAMS:
            raise ConfigError(f"unknown fault kind; known: {', '.join(FAULT_KINDS)}", at)
        if not isinstance(spec, dict):
            raise ConfigError("must be a table ({ count = N, ... })", at)
        known = {"count", "per_minute", *_PARAMS[kind]}
        for key in spec:
            if key not in known:
                raise ConfigError(f"unknown key for {kind}; known: {', '.join(sorted(known))}", f"{at}.{key}")
        if ("count" in spec) == ("per_minute" in spec):
            raise ConfigError("give exactly one of count and per_minute", at)
        count = None
        per_minute = None
        if "count" in spec:
            count = distribution(spec["count"], f"{at}.count")
            _check_range(count, (0.0, float(MAX_COUNT)), f"{at}.count")
            fractional = [v for v in fixed_values(count) if v != round(v)]
            if fractional:  # rounded half to even, 0.5 was no fault in any run, 2.5 two and 3.5 four
                raise ConfigError(
                    f"must be a whole number of faults, got {fractional[0]:g} (a draw of a distribution is "
                    "rounded to one; a number as written is not)",
                    f"{at}.count",
                )
        else:
            value = spec["per_minute"]
            if not (isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value <= 600):
                raise ConfigError(
                    f"must be a number of faults per minute in 0..600, got {value!r}", f"{at}.per_minute"
                )
            per_minute = float(value)
        for key in _REQUIRED.get(kind, ()):
            if key not in spec:
                raise ConfigError(f"required for {kind}", f"{at}.{key}")
        params: dict[str, Any] = {}
        for key, rng in _PARAMS[kind].items():
            if key not in spec:
                continue
            if rng is None:
                params[key] = _strings(kind, key, spec[key], f"{at}.{key}")
            else:
                params[key] = distribution(spec[key], f"{at}.{key}")
                _check_range(params[key], rng, f"{at}.{key}")
                if key == "duration_s" and not all(v > 0 for v in fixed_values(params[key])):
                    raise ConfigError("must be positive (a fault of no time is none)", f"{at}.{key}")
                if key == "offset_s" and 0.0 in fixed_values(params[key]):
                    why = "a clock jump of 0 s is none: firmware-sim --phone-jump refuses it"
                    raise ConfigError(f"must be non-zero ({why})", f"{at}.{key}")
        kinds.append(KindSpec(kind, count, per_minute, params))
    order = {k: i for i, k in enumerate(FAULT_KINDS)}
    return FaultSpec(tuple(sorted(kinds, key=lambda s: order[s.kind])))


def _strings(kind: str, key: str, value: Any, where: str) -> tuple[str, ...]:
    allowed = tuple(SPOOF_REASONS) if key == "spoof" else CHANNEL_SETS
    values = [value] if isinstance(value, str) else value
    if not isinstance(values, list) or not values or not all(isinstance(v, str) for v in values):
        raise ConfigError(f"must be one of {', '.join(allowed)} or a list of them, got {value!r}", where)
    bad = [v for v in values if v not in allowed]
    if bad:
        raise ConfigError(f"{bad[0]!r} is not one of {', '.join(allowed)}", where)
    return tuple(values)


def fixed_values(dist: Any, normal: bool = True) -> list[float]:
    """The values a distribution gives as they are written: a fixed value, a choice's values (any of
    which every so many runs draw: what a check of "never 0" must look at, not the fixed value alone), and
    with ``normal`` the mean of a normal of sigma 0 (a draw of a continuous one is never exactly one
    value)."""
    fixed = getattr(dist, "value", None)
    if fixed is None and normal and getattr(dist, "sigma", None) == 0.0:  # a normal of no spread: its mean
        fixed = getattr(dist, "mean", None)
    return [float(v) for v in ([fixed] if fixed is not None else list(getattr(dist, "values", ()) or ()))]


def _check_range(dist: Any, bounds: tuple[float, float], where: str) -> None:
    """Refuse a distribution that can draw outside ``bounds`` (its fixed value, limits, clip bounds), and a
    normal whose spread is wider than the whole range or is none at all.

    A normal's spread is its ``sigma``, or ``relative_sigma`` × |mean|. A count's or a parameter's nominal
    value is 0 (what :func:`draw_faults` hands the distribution), so ``relative_sigma`` without a non-zero
    ``mean`` is a spread of 0: every run drew 0 faults of a kind the file asks for (a fault campaign
    injecting nothing) or the shortest duration (1 ms stalls); one wide enough (``mean = 3,
    relative_sigma = 1e300``) had every run's draw on the range's ends (100 hangs, or none)."""
    lo, hi = bounds
    values = [getattr(dist, name, None) for name in ("value", "low", "high", "mean")]
    values += list(getattr(dist, "values", ()) or ())
    bad = [v for v in values if v is not None and not lo <= v <= hi]
    if bad:
        raise ConfigError(f"{bad[0]:g} is outside {lo:g}..{hi:g}", where)
    sigma, name = getattr(dist, "sigma", None), "sigma"
    relative = getattr(dist, "relative_sigma", None)
    if sigma is None and relative is not None:
        mean = abs(getattr(dist, "mean", None) or 0.0)
        if not mean > 0:
            raise ConfigError(
                "relative_sigma × |mean| is 0 here (the mean is 0, or not given: a fault's count and "
                "parameters have no nominal value to be relative to), so no run would be dispersed; give "
                "sigma (an absolute spread), or a non-zero mean",
                f"{where}.relative_sigma",
            )
        sigma, name = relative * mean, "relative_sigma"
    if sigma is not None and not sigma <= hi - lo:  # every draw clipped to the range's ends
        why = f"a sigma of {sigma:g} is wider than the whole range {lo:g}..{hi:g}"
        raise ConfigError(why, f"{where}.{name}")
    check_clip = getattr(dist, "check_clip", None)  # a normal's own low/high, about the 0 it is handed
    if check_clip is not None:
        check_clip(np.zeros(1), where, "the mean left out, 0 (a fault's count or parameter has no nominal)")


def check_board(kinds: Iterable[str], board: str, where: str) -> None:
    """Refuse ``kinds`` that ``board`` (``emulator``, ``firmware``) cannot be given (:data:`UNAVAILABLE`):
    a :class:`ConfigError` at ``where: faults.KIND`` naming the kind, the board and why."""
    refused = UNAVAILABLE.get(board, {})
    for kind in kinds:
        if kind in refused:
            raise ConfigError(
                f"the {kind!r} fault is not available with the {board} board ({refused[kind]}); "
                "leave it out (the shipped faults-firmware has every other kind)",
                f"{where}: faults.{kind}",
            )


def board_of(scenario: Scenario) -> str:
    """The board ``scenario``'s runs go through (``emu://?board=``): ``emulator`` unless it says."""
    return str(scenario.board_options.get("board", "emulator"))


# --------------------------------------------------------------------------- drawing a run's faults
def run_window_s(scenario: Scenario) -> float:
    """The span a run's faults are drawn over (s of the run's clock from its start): the warm-up, the
    spin-up and the run's duration — the whole run, from the handshake to the end of the hold."""
    return scenario.planned_length_s()


def check_rates(spec: FaultSpec, scenario: Scenario, where: str) -> None:
    """Refuse a kind's ``per_minute`` whose Poisson count over a run (:func:`run_window_s`) could pass
    :data:`MAX_COUNT` (its mean ``m`` with ``m + 5 √m`` above it): a draw is clipped there, so the rate
    the file asks for is not what runs get — 600 stalls a minute over the default run gave exactly 100 in
    every run, ~154 a minute and no Poisson spread, unsaid. The message gives the rate that fits."""
    window = run_window_s(scenario)
    for ks in spec.kinds:
        if ks.per_minute is None:
            continue
        expected = ks.per_minute * window / 60.0
        if expected + 5.0 * math.sqrt(expected) > MAX_COUNT:
            fits = _largest_rate(window)
            raise ConfigError(
                f"{ks.per_minute:g} a minute over a run's {window:g} s (warm-up, spin-up and duration) is "
                f"~{expected:.0f} {ks.kind} faults a run; a run takes at most {MAX_COUNT} of a kind (at most "
                f"{fits:.3g} a minute here)",
                f"{where}: faults.{ks.kind}.per_minute",
            )


def _largest_rate(window_s: float) -> float:
    """The largest rate (a minute) whose Poisson count over ``window_s`` stays within :data:`MAX_COUNT`
    with five standard deviations to spare: ``m + 5 √m = MAX_COUNT`` solved for ``m``."""
    root = (-5.0 + math.sqrt(25.0 + 4.0 * MAX_COUNT)) / 2.0
    return root * root * 60.0 / window_s


def draw_faults(spec: FaultSpec, scenario: Scenario, seed: int, index: int) -> tuple[InjectedFault, ...]:
    """Run ``index``'s faults, in time order: a pure function of (seed, index) per kind."""
    window = run_window_s(scenario)
    out: list[InjectedFault] = []
    for ks in spec.kinds:
        rng = np.random.default_rng([seed, index, zlib.crc32(f"faults.{ks.kind}".encode())])
        if ks.per_minute is not None:
            n = min(int(rng.poisson(ks.per_minute * window / 60.0)), MAX_COUNT)
        else:
            assert ks.count is not None
            n = round(_within(float(ks.count.sample(rng, np.zeros(1))[0]), (0.0, MAX_COUNT)))
        times = np.sort(rng.uniform(0.0, window, n))
        for t in times:
            out += _one(ks, float(t), rng, scenario)
    return tuple(sorted(out, key=lambda f: f.t))


def _within(value: float, bounds: tuple[float, float]) -> float:
    """``value`` clipped to ``bounds`` (NaN: the lower bound)."""
    lo, hi = bounds
    return lo if not value >= lo else min(value, hi)


def _one(ks: KindSpec, t: float, rng: np.random.Generator, scenario: Scenario) -> list[InjectedFault]:
    """One fault of ``ks`` at ``t`` with its parameters drawn (a Disarm with an Arm after it: two)."""
    params: dict[str, Any] = {}
    defaults = _DEFAULTS.get(ks.kind, {})
    for key, bounds in _PARAMS[ks.kind].items():
        if key in ks.params:
            value = ks.params[key]
            if isinstance(value, tuple):
                params[key] = str(rng.choice(value))
            else:  # a draw of a wide distribution (a normal's tail) kept within the kind's range
                assert bounds is not None
                params[key] = _within(float(value.sample(rng, np.zeros(1))[0]), bounds)
        elif key in defaults:
            value = defaults[key]
            if isinstance(value, tuple) and isinstance(value[0], float):
                params[key] = float(rng.uniform(*value))
            else:
                params[key] = str(rng.choice(value)) if isinstance(value, tuple) else value
    if ks.kind == "dead_esc":
        n = scenario.n_units
        pool = {"rotors": range(1, 2 * n, 2), "gimbals": range(0, 2 * n, 2), "any": range(2 * n)}
        params = {"channel": int(rng.choice(list(pool[params.pop("channels")])))}
    for key in ("duration_s", "arm_after_s"):
        if key in params:
            low = MIN_DURATION_S if key == "duration_s" else 0.0
            params[key] = min(max(params[key], low), MAX_DURATION_S if key == "duration_s" else 600.0)
    if ks.kind == "phone_jump" and params["offset_s"] == 0.0:  # a continuous draw of exactly 0 (a fixed
        params["offset_s"] = 1e-3  # 0 or a choice of one is refused as the file is read): the smallest jump
    arm_after = params.pop("arm_after_s", None)
    fault = InjectedFault(ks.kind, t, params)
    if ks.kind == "disarm" and arm_after is not None:
        return [fault, InjectedFault("arm", t + arm_after, {"after_disarm_s": arm_after})]
    return [fault]


# --------------------------------------------------------------------------- a run's faults, realised
_OPTIONS: dict[str, tuple[str, Callable[[float, Mapping[str, Any]], str]]] = {
    "stall": ("stall", lambda t, p: f"{t!r}:{p['duration_s']!r}"),
    "hang": ("hang_at", lambda t, p: repr(t)),
    "brownout": ("brownout_at", lambda t, p: repr(t)),
    "unplug": ("unplug", lambda t, p: f"{t!r}:{p['duration_s']!r}"),
    "noise": ("noise", lambda t, p: f"{t!r}:{p['duration_s']!r}:{p['corrupt']!r}"),
    "dead_esc": ("dead_esc", lambda t, p: f"{p['channel']}@{t!r}"),
    "phone_gap": ("phone_gap", lambda t, p: f"{t!r}:{p['duration_s']!r}"),
    "phone_jump": ("phone_jump", lambda t, p: f"{t!r}:{p['offset_s']!r}"),
    "phone_spoof": ("phone_spoof", lambda t, p: f"{t!r}:{p['spoof']}"),
}
"""Each board or world fault kind as the emulator's option (firmware-sim's, without dashes) and its value."""


def fault_options(faults: tuple[InjectedFault, ...], base: Mapping[str, Any]) -> dict[str, Any]:
    """The board's and the world's fault injection for ``faults`` (``emu://`` options, firmware-sim's
    command line), added to the scenario's own ``base`` options."""
    out: dict[str, Any] = {k: (list(v) if isinstance(v, list) else [v]) for k, v in base.items()}
    for f in faults:
        if f.kind in _OPTIONS:
            key, spell = _OPTIONS[f.kind]
            out.setdefault(key, []).append(spell(f.t, f.params))
    return out


def operator_schedule(faults: tuple[InjectedFault, ...]) -> list[tuple[float, OperatorCommand]]:
    """The operator's commands among ``faults``, as a :class:`~hil.runtime.operator.ScheduledOperator`
    takes them (origin ``campaign``)."""
    schedule = []
    for i, f in enumerate(f for f in faults if f.kind in OPERATOR_KINDS):
        target = None
        if f.kind == "slew":
            target = (f.params["roll_deg"], f.params["pitch_deg"], f.params["yaw_deg"])
        schedule.append((f.t, OperatorCommand(i + 1, f.kind, target, origin="campaign")))
    return schedule


def describe(faults: tuple[InjectedFault, ...]) -> str:
    """The drawn faults as one cell of ``runs.csv``: ``kind@t param=value;...``."""
    return ";".join(f.describe() for f in faults)


def counts(faults: tuple[InjectedFault, ...]) -> dict[str, int]:
    """Faults by kind."""
    out: dict[str, int] = {}
    for f in faults:
        out[f.kind] = out.get(f.kind, 0) + 1
    return out
