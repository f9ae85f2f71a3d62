"""Pulse outputs, sans-IO: per-channel servo pulses and PPM-sum trains (times in µs, no clocks here).

Servo pulses: each channel carries one pulse per frame, ``min_us``..``max_us`` wide (default 1000–2000),
at 50–490 Hz; the frame period must exceed the longest pulse. All channels rise together at the start of a
frame; frame ``k`` starts at ``floor(k · 10⁶ / rate)`` µs, an integer schedule that never drifts.

PPM-sum (one wire, several channels)::

      ┌─┐        ┌─┐           ┌─┐      ┌─┐                       ┌─┐
    ──┘ └────────┘ └───────────┘ └──────┘ └───────────────────────┘ └──   (marks ~300 µs high)
      |<- ch 0 ->|<-- ch 1 --->|<-ch 2->|<-------- sync ---------->|
      0          w0            w0+w1    w0+w1+w2                  22500

A channel's value is the time between consecutive rising edges (mark + space, 700–2300 µs accepted); a
frame of ``frame_us`` (22.5 ms) ends with a sync gap of at least ``min_sync_us`` (2.7 ms). ``encode_ppm``
gives one frame's rising-edge offsets; ``decode_ppm`` reads one frame back strictly (bad trains raise
:class:`ProtocolError` saying which interval); :class:`PpmDecoder` reads an endless stream of edge times the
way flight controllers do, tolerant of jitter, dropping bad frames with a counted reason.
"""

from __future__ import annotations

import enum
import math
import numbers
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from .errors import ConfigError, FieldRangeError, ProtocolError, value_repr
from .messages import PULSE_MAX_US, PULSE_MIN_US
from .numbers import real_number, whole_number

SERVO_MIN_RATE_HZ = 50.0
SERVO_MAX_RATE_HZ = 490.0


# =========================================================================== servo pulses
@dataclass(frozen=True)
class ServoParams:
    """Per-channel servo output: pulse limits (µs) and frame rate (Hz). Validated on construction
    (:class:`ConfigError` naming the field)."""

    min_us: int = 1000
    max_us: int = 2000
    frame_rate_hz: float = 50.0

    def __post_init__(self) -> None:
        w = "ServoParams"
        for name in ("min_us", "max_us"):
            v = getattr(self, name)
            whole = whole_number(v)
            if whole is None or not PULSE_MIN_US <= whole <= PULSE_MAX_US:
                raise ConfigError(
                    f"{value_repr(v)} is not an integer in {PULSE_MIN_US}..{PULSE_MAX_US} µs", f"{w}.{name}"
                )
            object.__setattr__(self, name, whole)  # numpy's integer as the int it is
        if not self.min_us < self.max_us:
            raise ConfigError(f"min_us {self.min_us} must be below max_us {self.max_us}", f"{w}.min_us")
        r = self.frame_rate_hz
        rate = real_number(r)
        if rate is None or not math.isfinite(rate):
            raise ConfigError(f"{value_repr(r)} is not a finite number", f"{w}.frame_rate_hz")
        if not SERVO_MIN_RATE_HZ <= r <= SERVO_MAX_RATE_HZ:
            raise ConfigError(
                f"{r:g} Hz is outside {SERVO_MIN_RATE_HZ:g}..{SERVO_MAX_RATE_HZ:g} Hz", f"{w}.frame_rate_hz"
            )
        if not self.min_period_us > self.max_us:
            raise ConfigError(
                f"the frame period {self.min_period_us} µs at {r:g} Hz does not exceed the longest pulse"
                f" ({self.max_us} µs)",
                f"{w}.frame_rate_hz",
            )

    @property
    def min_period_us(self) -> int:
        """The shortest frame period of the integer schedule (µs)."""
        return math.floor(1e6 / self.frame_rate_hz)

    def frame_start_us(self, k: int) -> int:
        """Start of frame ``k`` (µs from frame 0): ``floor(k · 10⁶ / rate)``. :class:`FieldRangeError`
        for a ``k`` that is not a frame number (an integer, not a bool, ≥ 0) or whose start is past a
        float's range (it was an ``OverflowError``, and NaN a ``ValueError``)."""
        frame = real_number(k) if isinstance(k, numbers.Integral) else None
        if frame is None or not 0 <= frame * 1e6 < math.inf:
            raise FieldRangeError("ServoParams.frame_start_us", "k", k)
        return math.floor(k * 1e6 / self.frame_rate_hz)

    def check(self, widths_us: Sequence[float], what: str = "servo") -> tuple[int, ...]:
        """``widths_us`` rounded to whole µs; :class:`FieldRangeError` naming the channel if one is not a
        finite number (a bool, a string, 10**400) or is outside ``min_us..max_us``."""
        out = []
        for ch, w in enumerate(widths_us):
            width = real_number(w)
            if width is None or not (math.isfinite(width) and self.min_us <= round(width) <= self.max_us):
                raise FieldRangeError(what, f"channel[{ch}]", w)
            out.append(round(width))
        return tuple(out)

    def frame(self, k: int, widths_us: Sequence[float]) -> tuple[ServoPulse, ...]:
        """The pulses of frame ``k``: every channel rises at the frame start."""
        t0 = self.frame_start_us(k)
        return tuple(ServoPulse(ch, t0, t0 + w) for ch, w in enumerate(self.check(widths_us)))


@dataclass(frozen=True, slots=True)
class ServoPulse:
    """One pulse on ``channel``: high from ``rise_us`` to ``fall_us``."""

    channel: int
    rise_us: float
    fall_us: float

    @property
    def width_us(self) -> float:
        return self.fall_us - self.rise_us


@dataclass(frozen=True, slots=True)
class ServoCapture:
    """What a captured servo channel carried: whole-µs widths, one per frame, and the mean frame rate."""

    widths_us: tuple[int, ...]
    frame_rate_hz: float


def measure_servo(
    pulses: Sequence[tuple[float, float]], params: ServoParams, tolerance_us: float = 5.0
) -> ServoCapture:
    """Read one channel's captured ``(rise_us, fall_us)`` pulses (e.g. a logic analyser on a real board)
    back into widths. Raises :class:`ProtocolError` naming the pulse if a width is outside the limits by
    more than ``tolerance_us`` or a rising edge comes less than a frame period (minus the tolerance)
    after the previous one, or if it is not a ``(rise_us, fall_us)`` pair of finite numbers; and
    :class:`FieldRangeError` for a ``tolerance_us`` that is not a finite number ≥ 0 (a NaN tolerance
    refused every pulse, saying the pulse was at fault)."""
    tolerance = real_number(tolerance_us)
    if tolerance is None or not (math.isfinite(tolerance) and tolerance >= 0.0):
        raise FieldRangeError("measure_servo", "tolerance_us", tolerance_us)
    if len(pulses) < 2:
        raise ProtocolError(f"servo capture: {len(pulses)} pulses; need at least 2 to measure a frame rate")
    pulses = [_captured_pulse(i, pulse) for i, pulse in enumerate(pulses)]
    widths = []
    period = 1e6 / params.frame_rate_hz
    for i, (rise, fall) in enumerate(pulses):
        w = fall - rise
        if not (math.isfinite(w) and params.min_us - tolerance_us <= w <= params.max_us + tolerance_us):
            raise ProtocolError(
                f"servo capture: pulse {i} at {rise:.1f} µs is {w:.1f} µs wide, outside"
                f" {params.min_us}..{params.max_us} µs"
            )
        if i and rise - pulses[i - 1][0] < period - tolerance_us:
            raise ProtocolError(
                f"servo capture: pulse {i} at {rise:.1f} µs comes {rise - pulses[i - 1][0]:.1f} µs after the"
                f" previous one, less than the {period:.1f} µs frame period"
            )
        widths.append(min(max(round(w), params.min_us), params.max_us))
    span = pulses[-1][0] - pulses[0][0]
    return ServoCapture(tuple(widths), (len(pulses) - 1) * 1e6 / span)


def _captured_pulse(i: int, pulse: object) -> tuple[float, float]:
    """Captured pulse ``i`` as ``(rise_us, fall_us)`` floats; :class:`ProtocolError` naming it if it is not
    a pair of finite numbers (a short tuple was a raw ``ValueError``, a string a ``TypeError``, an edge
    at 10**400 µs read exactly where every other time is a float)."""
    try:
        rise, fall = (real_number(t) for t in pulse)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        rise = fall = None
    if rise is None or fall is None or not (math.isfinite(rise) and math.isfinite(fall)):
        raise ProtocolError(
            f"servo capture: pulse {i} is {value_repr(pulse)}, not a (rise_us, fall_us) pair of finite µs"
        )
    return rise, fall


# =========================================================================== PPM-sum
@dataclass(frozen=True)
class PpmParams:
    """PPM-sum timing (µs). Encoding accepts 1..``max_channels`` channels of ``channel_min_us`` ..
    ``channel_max_us``; decoding accepts ``min_channels`` .. ``max_channels`` of them per frame."""

    frame_us: float = 22500.0
    separator_us: float = 300.0
    min_sync_us: float = 2700.0
    channel_min_us: float = 700.0
    channel_max_us: float = 2300.0
    max_channels: int = 8
    min_channels: int = 4

    def __post_init__(self) -> None:
        w = "PpmParams"
        for name in ("frame_us", "separator_us", "min_sync_us", "channel_min_us", "channel_max_us"):
            v = getattr(self, name)
            number = real_number(v)
            if number is None or not (math.isfinite(number) and number > 0):
                raise ConfigError(f"{value_repr(v)} is not a positive number", f"{w}.{name}")
        if not self.separator_us < self.channel_min_us < self.channel_max_us < self.min_sync_us:
            raise ConfigError(
                "need separator_us < channel_min_us < channel_max_us < min_sync_us", f"{w}.channel_min_us"
            )
        if not 1 <= self.min_channels <= self.max_channels <= 32:
            raise ConfigError("need 1 <= min_channels <= max_channels <= 32", f"{w}.max_channels")
        if self.max_channels * self.channel_max_us + self.min_sync_us > self.frame_us:
            raise ConfigError(
                f"{self.max_channels} channels of {self.channel_max_us:g} µs and a {self.min_sync_us:g} µs"
                f" sync do not fit a {self.frame_us:g} µs frame",
                f"{w}.frame_us",
            )


DEFAULT_PPM = PpmParams()


def encode_ppm(widths_us: Sequence[float], params: PpmParams = DEFAULT_PPM) -> tuple[float, ...]:
    """Rising-edge offsets (µs) of one PPM frame carrying ``widths_us``: ``0, w0, w0+w1, …, Σw`` (one
    more edge than channels: the last one closes the last channel; the sync gap follows until
    ``frame_us``). Raises :class:`FieldRangeError` naming the channel for a width outside
    ``channel_min_us..channel_max_us`` (a PPM output clamps its inputs first) or for too many channels."""
    n = len(widths_us)
    if not 1 <= n <= params.max_channels:
        raise FieldRangeError("PPM", "channels", n)
    edges = [0.0]
    for ch, w in enumerate(widths_us):
        width = real_number(w)
        if width is None or not (
            math.isfinite(width) and params.channel_min_us <= width <= params.channel_max_us
        ):
            raise FieldRangeError("PPM", f"channel[{ch}]", w)
        edges.append(edges[-1] + width)
    return tuple(edges)


def clamp_ppm_width(width_us: float, params: PpmParams = DEFAULT_PPM) -> float:
    """``width_us`` limited to the PPM channel range (what a PPM output stage does to its inputs): ±inf
    and widths past a float's range go to the ends. :class:`FieldRangeError` for one that is no width —
    NaN (it came out as NaN, as if clamped), a bool (``True`` came out as 700 µs), a string."""
    width = real_number(width_us)
    if width is None or math.isnan(width):
        raise FieldRangeError("clamp_ppm_width", "width_us", width_us)
    return min(max(width, params.channel_min_us), params.channel_max_us)


class PpmInterval(enum.Enum):
    """What the time between two rising edges is."""

    CHANNEL = "channel"  # channel_min_us .. channel_max_us
    SYNC = "sync"  # at least min_sync_us: the gap that ends a frame
    SHORT = "short"  # shorter than a channel: a glitch
    GAP = "gap"  # between the longest channel and the shortest sync: neither
    ORDER = "order"  # not after the previous edge (non-increasing or non-finite time)


def classify_interval(dt_us: float, params: PpmParams = DEFAULT_PPM) -> PpmInterval:
    """What ``dt_us`` (µs between two rising edges) is; :class:`FieldRangeError` if it is no number."""
    dt = real_number(dt_us)
    if dt is None:
        raise FieldRangeError("classify_interval", "dt_us", dt_us)
    return _classify(dt, params)


def _classify(dt_us: float, params: PpmParams) -> PpmInterval:
    """:func:`classify_interval` of a float."""
    if not (math.isfinite(dt_us) and dt_us > 0.0):
        return PpmInterval.ORDER
    if dt_us < params.channel_min_us:
        return PpmInterval.SHORT
    if dt_us <= params.channel_max_us:
        return PpmInterval.CHANNEL
    if dt_us < params.min_sync_us:
        return PpmInterval.GAP
    return PpmInterval.SYNC


def decode_ppm(edges_us: Sequence[float], params: PpmParams = DEFAULT_PPM) -> tuple[int, ...]:
    """The channel widths (whole µs) of one frame's rising-edge offsets, as :func:`encode_ppm` makes them
    (measured edges may carry jitter). Raises :class:`ProtocolError` saying which interval is bad or that
    the channel count is wrong. (The sync gap needs no check here: ``PpmParams`` guarantees that
    ``max_channels`` channels of the longest width leave at least ``min_sync_us`` of the frame.)"""
    n = len(edges_us) - 1
    if not params.min_channels <= n <= params.max_channels:
        raise ProtocolError(
            f"PPM frame: {len(edges_us)} edges = {n} channels;"
            f" need {params.min_channels}..{params.max_channels}"
        )
    edges = [real_number(t) for t in edges_us]
    for i, t in enumerate(edges):
        if t is None:
            raise ProtocolError(f"PPM frame: edge {i} is {value_repr(edges_us[i])}, not a time in µs")
    widths = []
    for i in range(n):
        a, b = edges[i], edges[i + 1]
        assert a is not None and b is not None
        kind = _classify(b - a, params)
        if kind is not PpmInterval.CHANNEL:
            raise ProtocolError(
                f"PPM frame: channel {i} (edges {a:.1f} -> {b:.1f} µs) is {b - a:.1f} µs, not a channel"
                f" ({params.channel_min_us:g}..{params.channel_max_us:g} µs): {kind.value}"
            )
        widths.append(round(b - a))
    return tuple(widths)


@dataclass(frozen=True, slots=True)
class PpmFrame:
    """A decoded frame: its first rising edge at ``t_us`` and the channel widths (whole µs)."""

    t_us: float
    channels: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class BadPpm:
    """A frame (or the start of one) that was dropped, and why; ``t_us`` is the edge that revealed it."""

    t_us: float
    reason: PpmInterval | str
    detail: str


@dataclass
class PpmCounters:
    edges: int = 0
    frames: int = 0
    dropped: dict[str, int] = field(default_factory=dict)  # reason → count
    reanchored: int = 0  # times the edge held was found the absurd one and the stream taken up anew


class PpmDecoder:
    """Stream decoder: feed rising-edge times (µs, any origin, increasing); get :class:`PpmFrame` and
    :class:`BadPpm` events. Like a flight controller's PPM input it waits for a sync gap, collects channel
    intervals until the next sync, and drops the frame on a glitch, an out-of-range interval or a wrong
    channel count, then resynchronises at the next sync. Memory is bounded (one frame).

    An edge that does not come after the one held is dropped and the held one kept (a timestamp from the
    past). Two in a row, in order between themselves, say the held one was the absurd one — a glitch far
    in the future (1e160 µs), or a first edge that was NaN or inf: kept, it put every later edge "before"
    it and the decoder dropped the whole stream from there on. The stream is then taken up anew at the
    second (``counters.reanchored``) and decodes again from the next sync."""

    def __init__(self, params: PpmParams = DEFAULT_PPM) -> None:
        self.params = params
        self.counters = PpmCounters()
        self._last: float | None = None
        self._behind: float | None = None  # the edge just dropped for not coming after ``_last``
        self._synced = False
        self._start = 0.0
        self._channels: list[int] = []

    def feed(self, edges_us: Iterable[float]) -> list[PpmFrame | BadPpm]:
        """Events for ``edges_us``. A capture counter's integer beyond a float's range (10**400) is an edge
        at ±inf — absurdly far, which the decoder takes up as any absurd edge. One that is no number (a
        string, None, a bool) is counted and drops the frame it fell in (``not_a_time``), the edge held
        kept: it was a raw ``TypeError`` out of here, and ``"1500"`` was read as a time."""
        events: list[PpmFrame | BadPpm] = []
        for t in edges_us:
            edge = real_number(t)
            if edge is None:
                self.counters.edges += 1
                held = math.nan if self._last is None else self._last
                self._drop(events, held, "not_a_time", f"edge {value_repr(t)} is not a time in µs")
                continue
            self._edge(edge, events)
        return events

    def _edge(self, t: float, events: list[PpmFrame | BadPpm]) -> None:
        self.counters.edges += 1
        last, self._last = self._last, t
        if last is None:
            return
        dt = t - last
        kind = _classify(dt, self.params)
        behind, self._behind = self._behind, None
        if kind is PpmInterval.ORDER:
            if behind is not None and t > behind:  # the held edge is ahead of two in order: it was absurd
                self.counters.reanchored += 1
                self._synced, self._channels = False, []
                return  # ``t`` is the edge held: the stream goes on from it, decoding from the next sync
            self._last, self._behind = last, t  # keep the edge held; drop this one
            self._drop(
                events, t, kind, f"edge at {value_repr(t)} µs does not come after {value_repr(last)} µs"
            )
        elif kind is PpmInterval.SYNC:
            if self._synced and self._channels:
                self._end_frame(events, t)
            self._synced, self._start, self._channels = True, t, []
        elif kind is PpmInterval.CHANNEL:
            if not self._synced:
                return
            self._channels.append(round(dt))
            if len(self._channels) > self.params.max_channels:
                self._drop(
                    events, t, "too_many", f"more than {self.params.max_channels} channels before a sync"
                )
        elif self._synced:
            self._drop(events, t, kind, f"{dt:.1f} µs between edges at {last:.1f} and {t:.1f} µs")

    def _end_frame(self, events: list[PpmFrame | BadPpm], t: float) -> None:
        n = len(self._channels)
        if n < self.params.min_channels:
            self._drop(events, t, "too_few", f"{n} channels before the sync at {t:.1f} µs")
            return
        self.counters.frames += 1
        events.append(PpmFrame(self._start, tuple(self._channels)))

    def _drop(
        self, events: list[PpmFrame | BadPpm], t: float, reason: PpmInterval | str, detail: str
    ) -> None:
        key = reason.value if isinstance(reason, PpmInterval) else reason
        self.counters.dropped[key] = self.counters.dropped.get(key, 0) + 1
        events.append(BadPpm(t, reason, detail))
        self._synced, self._channels = False, []
