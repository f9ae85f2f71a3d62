"""Widths below the microsecond (protocol.pulse_widths): fine widths, the sigma-delta over frames, what
telemetry reports. The C firmware does the same integer arithmetic; the conformance suite checks its pins."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.errors import FieldRangeError
from protocol.messages import PULSE_MAX_US
from protocol.pulse_widths import FINE_PER_US, TICK_US, SigmaDelta, fine_width, reported_us, whole_us

WIDTHS_US = st.floats(500.0, PULSE_MAX_US, allow_nan=False)


def test_fine_widths_round_half_to_even_like_the_firmware():
    assert fine_width(1457.391) == 746184  # 1457.391 × 512 = 746184.19
    assert fine_width(1500.0) == whole_us(1500) == 1500 * 512
    assert fine_width(1000.5 / 512) == 1000 and fine_width(1001.5 / 512) == 1002  # lrintf: ties to even
    assert reported_us(746184) == 1457 and reported_us(fine_width(1457.5)) == 1458  # half up
    for bad in (math.nan, math.inf, -0.1, PULSE_MAX_US + 0.01):
        with pytest.raises(FieldRangeError, match="width_us"):
            fine_width(bad)


@given(WIDTHS_US, st.integers(1, 600), st.integers(0, 255))
def test_any_run_of_frames_adds_up_to_the_fine_width_within_one_tick(width, frames, start):
    q = fine_width(width)
    dither = SigmaDelta(1)
    dither.residue = [start]  # wherever the channel's remainder happens to stand
    out = [dither.frame((q,))[0] for _ in range(frames)]
    low = (q >> 8) * TICK_US
    assert set(out) <= {low, low + TICK_US}  # whole ticks, the two around the width
    assert abs(sum(out) - frames * q / FINE_PER_US) < TICK_US  # the mean: the fine width ± a tick / frames


@given(st.lists(st.one_of(st.none(), WIDTHS_US), min_size=1, max_size=12), st.integers(1, 50))
def test_channels_dither_independently_and_without_pulses_keep_their_remainder(widths, frames):
    fine = [None if w is None else fine_width(w) for w in widths]
    together = SigmaDelta(len(fine))
    rows = [together.frame(fine) for _ in range(frames)]
    for ch, q in enumerate(fine):
        if q is None:
            assert all(r[ch] is None for r in rows) and together.residue[ch] == 0
            continue
        alone = SigmaDelta(1)
        assert [r[ch] for r in rows] == [alone.frame((q,))[0] for _ in range(frames)]


def test_whole_ticks_go_out_exactly_and_a_reset_clears_the_remainders():
    dither = SigmaDelta(2)
    q = fine_width(1510.15)  # a gimbal rate of ~1e-3 rad/s just past the default map's dead zone
    widths = [dither.frame((q, whole_us(1000)))[0:2] for _ in range(20)]
    assert {w[1] for w in widths} == {1000.0}
    assert [w[0] for w in widths].count(1510.5) == 6  # 0.15 µs of 0.5: 30 % of the frames
    assert dither.residue[0] != 0
    dither.reset()
    assert dither.residue == [0, 0]
