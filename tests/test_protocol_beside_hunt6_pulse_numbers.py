"""Beside the tested widths and times (floats in or near range, NaN, inf): values that parse but are no width
or time, given to every public entry point of ``protocol.pulses`` and ``protocol.pulse_widths``.

An integer beyond a float's range (10**400) was an ``OverflowError`` out of ``fine_width``,
``ServoParams.check``, ``encode_ppm``, ``classify_interval``, ``decode_ppm`` and
``ServoParams(frame_rate_hz=)``; a bool was taken as a number (``fine_width(True)`` a 1 µs pulse,
``clamp_ppm_width(True)`` 700 µs);
``clamp_ppm_width(nan)`` gave NaN back as if clamped; a string was a raw ``TypeError`` (or, as a PPM edge,
``"1500"`` read as a time); ``SigmaDelta.frame`` with more widths than channels an ``IndexError``, with a
negative fine width a negative pulse, with a float one a ``TypeError``; ``whole_us(1.5)`` a float fine width,
``reported_us(-1)`` 0 µs; ``frame_start_us(nan)`` a ``ValueError``; a short captured pulse a raw
``ValueError``. Now each is refused with the protocol's typed error naming the argument (the stream decoder
counts and drops it), and numpy's scalars and 0-d arrays are the numbers they hold."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from protocol.errors import ConfigError, FieldRangeError, HilError, ProtocolError
from protocol.pulse_widths import FINE_MAX, SigmaDelta, fine_width, reported_us, whole_us
from protocol.pulses import (
    PpmDecoder,
    PpmParams,
    ServoParams,
    clamp_ppm_width,
    classify_interval,
    decode_ppm,
    encode_ppm,
    measure_servo,
)

NO_NUMBER = st.sampled_from([True, False, np.bool_(True), "1500", None, b"1", [1500.0], np.array([1500.0])])
HUGE = st.sampled_from([10**400, -(10**400), 10**309, 2**1024])
NOT_FINITE = st.sampled_from([math.nan, math.inf, -math.inf, np.float64("nan"), np.float32("inf")])
ABSURD = st.one_of(NO_NUMBER, HUGE, NOT_FINITE)

SERVO = ServoParams()


def _entry_points(bad: object) -> dict[str, tuple[type[HilError], str, object]]:
    """Each public entry point given ``bad`` where a number is meant: (the error it must raise, a phrase
    the error names it by, the call)."""
    return {
        "fine_width": (FieldRangeError, "width_us", lambda: fine_width(bad)),
        "whole_us": (FieldRangeError, "width_us", lambda: whole_us(bad)),
        "reported_us": (FieldRangeError, "fine", lambda: reported_us(bad)),
        "SigmaDelta": (ConfigError, "channels", lambda: SigmaDelta(bad)),
        "SigmaDelta.frame": (FieldRangeError, r"fine\[1\]", lambda: SigmaDelta(2).frame((512_000, bad))),
        "ServoParams.check": (FieldRangeError, r"channel\[1\]", lambda: SERVO.check([1500, bad])),
        "ServoParams.frame": (FieldRangeError, "k", lambda: SERVO.frame(bad, [1500])),
        "ServoParams": (ConfigError, "frame_rate_hz", lambda: ServoParams(frame_rate_hz=bad)),
        "PpmParams": (ConfigError, "separator_us", lambda: PpmParams(separator_us=bad)),
        "encode_ppm": (FieldRangeError, r"channel\[2\]", lambda: encode_ppm([1500, 1500, bad, 1500])),
        "decode_ppm": (ProtocolError, "edge 2|channel 1", lambda: decode_ppm([0, 1500, bad, 4500, 6000])),
        "measure_servo": (
            ProtocolError,
            "pulse 1",
            lambda: measure_servo([(0.0, 1500.0), (bad, 21500.0), (40000.0, 41500.0)], SERVO),
        ),
        "measure_servo tolerance": (
            FieldRangeError,
            "tolerance_us",
            lambda: measure_servo([(0.0, 1500.0), (20000.0, 21500.0)], SERVO, tolerance_us=bad),
        ),
    }


@settings(max_examples=300, deadline=None)
@given(bad=ABSURD, entry=st.sampled_from(sorted(_entry_points(0))))
def test_an_absurd_number_is_refused_with_a_typed_error_naming_the_argument(bad, entry):
    assume(not (entry == "SigmaDelta.frame" and bad is None))  # None there is "no pulse"
    error, where, call = _entry_points(bad)[entry]
    with pytest.raises(error, match=where):
        call()


@settings(max_examples=100, deadline=None)
@given(bad=st.one_of(NO_NUMBER, st.sampled_from([math.nan])))
def test_clamp_and_classify_refuse_what_is_no_width_and_clamp_the_far_ones(bad):
    with pytest.raises(FieldRangeError, match="width_us"):
        clamp_ppm_width(bad)
    if not isinstance(bad, float):
        with pytest.raises(FieldRangeError, match="dt_us"):
            classify_interval(bad)
    assert clamp_ppm_width(10**400) == 2300.0 and clamp_ppm_width(-math.inf) == 700.0


@settings(max_examples=100, deadline=None)
@given(bad=st.lists(st.one_of(NO_NUMBER, HUGE), min_size=1, max_size=4), seed=st.integers(0, 2**16))
def test_the_stream_decoder_counts_an_edge_that_is_no_time_and_decodes_on(bad, seed):
    frame = [0.0, 1500.0, 3000.0, 4500.0, 6000.0]
    period = 22500.0
    edges: list[object] = [k * period + t for k in range(3) for t in frame]
    at = 5 + seed % 5  # somewhere in the second frame
    edges[at:at] = bad
    edges += [k * period + t for k in range(3, 6) for t in frame]
    decoder = PpmDecoder()
    events = decoder.feed(edges)
    frames = [e for e in events if not hasattr(e, "reason")]
    assert all(f.channels == (1500, 1500, 1500, 1500) for f in frames)
    assert [f.t_us for f in frames][-2:] == [
        3 * period,
        4 * period,
    ]  # decoding again after it (the last, unclosed)
    assert decoder.counters.edges == len(edges)
    no_time = sum(1 for b in bad if not isinstance(b, int) or isinstance(b, bool))
    assert decoder.counters.dropped.get("not_a_time", 0) == no_time


@settings(max_examples=100, deadline=None)
@given(width=st.floats(500.0, 2500.0), wrap=st.sampled_from([np.float64, np.float32, np.array]))
def test_numpy_scalars_and_0d_arrays_are_the_numbers_they_hold(width, wrap):
    value = wrap(width)
    assert fine_width(value) == fine_width(float(value))
    assert clamp_ppm_width(value) == clamp_ppm_width(float(value))
    assert SigmaDelta(1).frame((np.int64(fine_width(value)),)) == SigmaDelta(1).frame((fine_width(value),))


def test_a_refused_frame_leaves_the_dither_as_it_was():
    dither = SigmaDelta(2)
    dither.frame((fine_width(1500.3), fine_width(1500.7)))
    before = list(dither.residue)
    for bad in (
        (fine_width(1500.3), -5),
        (fine_width(1500.3), FINE_MAX + 1),
        (1, 2, 3),
        (fine_width(1500.3), 1.5),
    ):
        with pytest.raises(FieldRangeError, match="SigmaDelta.frame"):
            dither.frame(bad)
        assert dither.residue == before
