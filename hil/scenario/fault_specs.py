"""The board's fault options as text (firmware-sim's ``--stall 5:2``, ``--sag 6@10/5``, ``--dead-esc 1@3``, a
scenario's ``[faults]`` table): parsed, and held to the ranges a fault can have, in one place for both
sides. A scenario's table is checked as its file is read (an error names the file and the key); firmware-sim
checks its command line with the same functions (an error names the option). Before, a scenario's
``hang_at = "nan"`` surfaced as ``faults.at`` from the board's constructor, a run and a warm-up later, and
``stall = "-5:-1"`` was taken by firmware-sim's parser for an option of its own.

Every time (``AT``) is board seconds from its start, finite, ``0 .. MAX_DURATION_S``; every duration and
ramp finite and ``>= 0`` (a stall's and a gap's ``> 0``), at most ``MAX_DURATION_S``."""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from typing import Any

from protocol.errors import ConfigError, value_repr

MAX_DURATION_S = 86_400.0
"""The longest time a fault option may name (a day: the longest run a scenario may ask for)."""
MAX_SAG_V = 100.0
"""The largest battery sag (V): more than any pack the board takes (12 cells, 50.4 V full) collapses."""
MAX_SAG_OHMS = 100.0
"""The largest extra internal resistance (Ω): a pack of 100 Ω delivers nothing a motor could use."""
DIRECTIONS = ("rx", "tx", "both")
_NUMBER = r"[0-9.eE+-]+"
_AT = rf"(?:@(?P<at>{_NUMBER}))?"


def _time(value: float, option: str, what: str = "time") -> float:
    if not (math.isfinite(value) and 0.0 <= value <= MAX_DURATION_S):
        raise ConfigError(f"{value_repr(value)} is not a {what} of 0..{MAX_DURATION_S:g} s", option)
    return value


def _duration(value: float, option: str, positive: bool) -> float:
    if not (math.isfinite(value) and (value > 0.0 if positive else value >= 0.0) and value <= MAX_DURATION_S):
        bound = "> 0" if positive else ">= 0"
        raise ConfigError(
            f"{value_repr(value)} is not a duration {bound} and at most {MAX_DURATION_S:g} s", option
        )
    return value


def _float(text: str, spec: str, option: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(f"{value_repr(spec)}: not a number", option) from None


def parse_sag(
    spec: str, option: str = "--sag", limit: float = MAX_SAG_V
) -> tuple[float, float | None, float]:
    """``AMOUNT[@AT[/RAMP]]`` → (amount ``0..limit``, at or None: now, ramp seconds)."""
    m = re.fullmatch(rf"(?P<v>{_NUMBER})(?:@(?P<at>{_NUMBER})(?:/(?P<ramp>{_NUMBER}))?)?", spec.strip())
    if not m:
        raise ConfigError(f"{value_repr(spec)} is not AMOUNT[@AT[/RAMP]] (e.g. 6@10/5)", option)
    amount = _float(m["v"], spec, option)
    if not (math.isfinite(amount) and 0.0 <= amount <= limit):
        raise ConfigError(f"{value_repr(spec)}: the amount must be 0..{limit:g}", option)
    at = None if m["at"] is None else _time(_float(m["at"], spec, option), option)
    ramp = 0.0 if m["ramp"] is None else _duration(_float(m["ramp"], spec, option), option, positive=False)
    return amount, at, ramp


def parse_stall(spec: str, option: str = "--stall") -> tuple[float, float]:
    """``AT:DURATION`` → (at, duration > 0) seconds (a stall, a phone gap, an unplug, a USB detach)."""
    m = re.fullmatch(rf"(?P<at>{_NUMBER}):(?P<d>{_NUMBER})", spec.strip())
    if not m:
        raise ConfigError(f"{value_repr(spec)} is not AT:DURATION (e.g. 5:2)", option)
    at = _time(_float(m["at"], spec, option), option)
    return at, _duration(_float(m["d"], spec, option), option, positive=True)


def parse_numbers(spec: str, count: int, option: str, example: str) -> tuple[float, ...]:
    """``A:B[:C]`` — ``count`` finite numbers separated by colons."""
    parts = spec.strip().split(":")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise ConfigError(f"{value_repr(spec)}: not numbers (e.g. {example})", option) from None
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ConfigError(
            f"{value_repr(spec)} is not {count} finite numbers separated by ':' (e.g. {example})", option
        )
    return values


def parse_noise(spec: str, option: str = "--noise") -> tuple[float, float, float]:
    """``AT:DURATION:P`` → (at, duration > 0, per-byte corruption probability ``0..1``)."""
    at, duration, p = parse_numbers(spec, 3, option, "8:1.5:0.02")
    _time(at, option)
    _duration(duration, option, positive=True)
    if not 0.0 <= p <= 1.0:
        raise ConfigError(f"{value_repr(spec)}: {value_repr(p)} is not a probability 0..1", option)
    return at, duration, p


def parse_jump(spec: str, option: str = "--phone-jump") -> tuple[float, float]:
    """``AT:OFFSET`` → (at, the phone clock's jump, non-zero, at most a day either way, s)."""
    at, offset = parse_numbers(spec, 2, option, "12:-100")
    _time(at, option)
    if offset == 0.0 or abs(offset) > MAX_DURATION_S:
        raise ConfigError(
            f"{value_repr(spec)}: the offset must be non-zero and within ±{MAX_DURATION_S:g} s", option
        )
    return at, offset


def parse_spoof(spec: str) -> tuple[float, str]:
    """``AT:KIND`` → (at 0..a day, kind) (the kind is the world's to check)."""
    at, sep, kind = spec.strip().partition(":")
    try:
        t = float(at)
    except ValueError:
        t = math.nan
    if not sep or not math.isfinite(t):
        raise ConfigError(f"{value_repr(spec)} is not AT:KIND (e.g. 12.5:huge)", "--phone-spoof")
    return _time(t, "--phone-spoof"), kind  # within a day, as every fault's time (1e300 never fired)


def parse_dead_esc(spec: str, option: str = "--dead-esc") -> tuple[int, float | None]:
    """``CHANNEL[@AT]`` → (channel, at or None: now); the channel's range is the board's to check."""
    m = re.fullmatch(r"(?P<ch>[0-9]+)" + _AT, spec.strip())
    if not m:
        raise ConfigError(f"{value_repr(spec)} is not CHANNEL[@AT] (e.g. 1@3)", option)
    at = None if m["at"] is None else _time(_float(m["at"], spec, option), option)
    return int(m["ch"]), at


def parse_probability(value: str, option: str) -> float:
    """A per-byte probability, ``0..1``."""
    p = _float(value, value, option)
    if not (math.isfinite(p) and 0.0 <= p <= 1.0):
        raise ConfigError(f"{value_repr(value)} is not a probability 0..1", option)
    return p


def parse_time(value: str, option: str) -> float:
    """A fault's time (``--hang-at``, ``--brownout-at``)."""
    return _time(_float(value, value, option), option)


def parse_direction(value: str, option: str) -> str:
    if value not in DIRECTIONS:
        raise ConfigError(f"{value_repr(value)} is not one of {', '.join(DIRECTIONS)}", option)
    return value


FAULT_OPTIONS: dict[str, Callable[[str, str], Any]] = {
    "corrupt": parse_probability,
    "drop": parse_probability,
    "fault_direction": parse_direction,
    "stall": parse_stall,
    "hang_at": parse_time,
    "sag": parse_sag,
    "sag_ohms": lambda spec, option: parse_sag(spec, option, MAX_SAG_OHMS),
    "brownout_at": parse_time,
    "dead_esc": parse_dead_esc,
}
"""A scenario's ``[faults]`` keys (firmware-sim's options) and the parser each value must pass."""
ONE_VALUE = frozenset({"corrupt", "drop", "fault_direction"})
"""The ``[faults]`` keys that take one value: firmware-sim's options that do not repeat (a link's noise
and its direction are one setting), so a list of them is refused as the file is read — it was refused by
the board at connection, naming neither file nor key, and a campaign ran every run into it."""


TIMED: dict[str, Callable[[Any], float]] = {
    "stall": lambda parsed: parsed[0],
    "hang_at": lambda parsed: parsed,
    "sag": lambda parsed: parsed[1] or 0.0,
    "sag_ohms": lambda parsed: parsed[1] or 0.0,
    "brownout_at": lambda parsed: parsed,
    "dead_esc": lambda parsed: parsed[1] or 0.0,
}
"""The ``[faults]`` keys that happen at a time, and that time (board s) from the key's parsed value (an
``AT`` left out: at once)."""


def fault_times(options: Mapping[str, Any]) -> list[tuple[str, float]]:
    """Each timed fault of a (checked) ``[faults]`` table: ``key = value`` as written, and when it comes
    (board s from its start)."""
    times = []
    for key, value in options.items():
        if key not in TIMED:
            continue
        for item in value if isinstance(value, list) else [value]:
            times.append((f"{key} = {value_repr(item)}", TIMED[key](FAULT_OPTIONS[key](str(item), key))))
    return times


def check_fault_options(options: Mapping[str, Any], n_channels: int, where: str) -> None:
    """A scenario's ``[faults]`` table (values: a number or a string, or a list of them) through the
    parsers of :data:`FAULT_OPTIONS`, a dead ESC's channel one of the board's ``n_channels``: a
    :class:`ConfigError` at ``where.key`` (``where``: the file and the table) for the first that fails."""
    for key, value in options.items():
        parse = FAULT_OPTIONS[key]
        if key in ONE_VALUE and isinstance(value, list):
            if len(value) != 1:
                raise ConfigError(f"takes one value, not a list of {len(value)}", f"{where}.{key}")
        for item in value if isinstance(value, list) else [value]:
            parsed = parse(str(item), f"{where}.{key}")
            if key == "dead_esc" and parsed[0] >= n_channels:
                raise ConfigError(
                    f"channel {parsed[0]} does not exist (the board has {n_channels})", f"{where}.{key}"
                )
