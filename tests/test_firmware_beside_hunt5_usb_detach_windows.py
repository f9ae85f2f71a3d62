"""Beside ``--usb-detach AT:DURATION`` (``FirmwareBoard.detach_phone``): windows that overlap, and windows
shorter than the board's 1 µs time step.

Each window was two harness commands, a detach at its start and an attach at its end, sorted by time. A
window inside another plugged the phone back at its own end, the outer outage silently cut short; a window
shorter than half a microsecond rounded to 0 µs, its "attach" sorted before its "detach" at the same
instant, and the phone stayed off the port for good - a run that asked for a glitch lost its phone. Now
windows count: the phone leaves the port as the first open window begins and comes back as the last one
ends (their union), and a window lasts at least 1 µs.

The firmware under simavr in lockstep (``FirmwareBoard`` with ``usb``), the phone's mode read from the
harness's MAX3421E model (``usbstate``)."""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from hypothesis import example, given, settings

from firmware_sim.avr.harness import HarnessOptions
from firmware_sim.avr.stepped import FirmwareBoard
from firmware_sim.board.config import BoardConfig
from hil.timing.clock import LockstepClock

pytestmark = pytest.mark.firmware

PHONE_DETACHED = 0
TICK_S = 1e-6  # the board's time step: a window lasts at least this long

WINDOW = st.tuples(
    st.integers(2, 30).map(lambda tenths: tenths / 10),  # at (s of board time)
    st.one_of(st.floats(1e-12, 4e-7), st.integers(1, 25).map(lambda tenths: tenths / 10)),  # duration (s)
)


def _union(windows: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The outages the windows make: overlapping or touching ones merged, each at least TICK_S long."""
    merged: list[list[float]] = []
    for at, duration in sorted(windows):
        end = at + max(duration, TICK_S)
        if merged and at <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], end)
        else:
            merged.append([at, end])
    return [(a, b) for a, b in merged]


@settings(max_examples=6, deadline=None)
@given(windows=st.lists(WINDOW, min_size=1, max_size=4))
@example(windows=[(1.0, 2.0), (1.5, 0.3)])  # a window inside another: off until 3.0 s, not back at 1.8 s
@example(windows=[(0.5, 0.5), (1.0, 0.5)])  # touching: one outage of 1 s
@example(windows=[(0.2, 1e-12), (0.5, 0.1)])  # unplugged while it switches to accessory mode: stays off
def test_the_phone_is_off_the_port_exactly_over_the_union_of_the_windows(windows) -> None:
    outages = _union(windows)
    probes: list[tuple[float, bool]] = []  # (s of board time, the phone should be off the port)
    for start, end in outages:
        if end - start >= 0.01:
            probes.append(((start + end) / 2, True))
        probes.append((end + 0.005, False))
    probes = [p for p in sorted(probes) if not any(a <= p[0] < b for a, b in outages) or p[1]]
    clock = LockstepClock()
    with FirmwareBoard(BoardConfig(n_units=1), clock=clock, options=HarnessOptions(usb=True)) as board:
        for at, duration in windows:
            board.detach_phone(duration, at=at)
        for t, off in probes:
            clock.set(t)
            board.step()
            mode = board.usb_state().mode
            assert (mode == PHONE_DETACHED) == off, (t, mode, windows, outages)


def test_a_glitch_shorter_than_a_microsecond_leaves_the_phone_plugged_in_and_switched() -> None:
    clock = LockstepClock()
    with FirmwareBoard(BoardConfig(n_units=1), clock=clock, options=HarnessOptions(usb=True)) as board:
        board.detach_phone(1e-7, at=0.5)
        for t in (0.6, 3.0):
            clock.set(t)
            board.step()
        usb = board.usb_state()
        assert usb.mode == 2, usb  # back, enumerated and switched into accessory mode again
        assert usb.error == ""
