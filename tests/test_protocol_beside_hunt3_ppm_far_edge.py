"""Beside the tested PPM glitches (a short spike, a timestamp from the past): one edge far in the future
(1e160 µs, a capture counter's garbage), or a first edge that is NaN or inf. ``PpmDecoder`` kept it as the
edge to measure from, so every honest edge after it came "before" it and was dropped: the decoder lost the
whole stream from there on, however long it ran."""

from __future__ import annotations

import math

import hypothesis.strategies as st
from hypothesis import given, settings

from protocol.pulses import PpmDecoder, PpmFrame, encode_ppm

FRAME_US = 22500.0


def stream(frames: list[list[int]]) -> list[float]:
    """The rising edges (µs) of ``frames`` sent back to back, one every ``FRAME_US``."""
    edges: list[float] = []
    for k, widths in enumerate(frames):
        edges += [k * FRAME_US + e for e in encode_ppm(widths)]
    return edges + [len(frames) * FRAME_US]


@settings(max_examples=200, deadline=None)
@given(
    frames=st.lists(st.lists(st.integers(900, 2100), min_size=4, max_size=8), min_size=8, max_size=14),
    glitch_frame=st.integers(0, 3),
    glitch_edge=st.integers(0, 8),
    glitch=st.sampled_from([1e160, 1e12, 2.0**53, math.inf, math.nan]),
    chunk=st.integers(1, 50),
)
def test_one_absurd_edge_costs_a_few_frames_not_the_stream(
    frames: list[list[int]], glitch_frame: int, glitch_edge: int, glitch: float, chunk: int
) -> None:
    edges = stream(frames)
    first = sum(len(f) + 1 for f in frames[:glitch_frame])
    at = first + min(glitch_edge, len(frames[glitch_frame]))
    value = glitch if at == 0 or not math.isfinite(glitch) else edges[at - 1] + glitch
    edges.insert(at, value)  # a NaN/inf edge anywhere, or the first edge; a finite one far ahead
    decoder = PpmDecoder()
    events = []
    for i in range(0, len(edges), chunk):
        events += decoder.feed(edges[i : i + chunk])
    decoded = {round(e.t_us / FRAME_US): e.channels for e in events if isinstance(e, PpmFrame)}
    # every frame from the second after the glitch's on, but the last (it ends at the stream's end)
    for k in range(glitch_frame + 2, len(frames) - 1):
        assert decoded.get(k) == tuple(frames[k]), (k, sorted(decoded), decoder.counters)
    assert decoder.counters.frames == len(decoded)


@settings(max_examples=60, deadline=None)
@given(
    frames=st.lists(st.lists(st.integers(900, 2100), min_size=4, max_size=8), min_size=6, max_size=10),
    at=st.integers(0, 10),  # within the first three frames: the second after it on decodes
    sign=st.sampled_from([1, -1]),
)
def test_an_integer_edge_beyond_a_floats_range_is_an_absurd_edge_not_an_overflow(
    frames: list[list[int]], at: int, sign: int
) -> None:
    """A capture counter's integer of 10**400 µs was an ``OverflowError`` out of ``feed``."""
    edges: list[float] = list(stream(frames))
    edges.insert(min(at, len(edges)), sign * 10**400)
    decoder = PpmDecoder()
    events = decoder.feed(edges)
    decoded = {round(e.t_us / FRAME_US): e.channels for e in events if isinstance(e, PpmFrame)}
    assert decoded.get(len(frames) - 2) == tuple(frames[-2])
    assert decoder.counters.edges == len(edges)
