"""The emulated hobby ESC (firmware_sim.board.esc): factory endpoints, arming at minimum, endpoint
programming, and its replay over recorded pulse frames."""

from __future__ import annotations

import pytest

from firmware_sim.board.esc import EmulatedEsc, EscMode, EscParams, replay_esc

P = EscParams()  # factory 1100..1900 us, programming above 1700 us, 1.0 s / 0.5 s acknowledgements


def drive(
    esc: EmulatedEsc, t0: float, t1: float, pulse: float | None, powered: bool = True, dt: float = 0.02
):
    """Frames every ``dt`` s from ``t0`` to ``t1`` (exclusive) with one pulse width; returns ``t1``."""
    n = round((t1 - t0) / dt)
    for k in range(n):
        esc.update(t0 + k * dt, pulse, powered)
    return t1


def test_an_esc_leaves_the_factory_with_its_endpoints_and_arms_only_at_minimum():
    esc = EmulatedEsc()
    assert (esc.low_us, esc.high_us, esc.mode) == (1100.0, 1900.0, EscMode.OFF)
    t = drive(esc, 0.0, 0.5, 1500)  # powered up with a mid-range stick: it waits, motor off
    assert esc.mode is EscMode.WAITING and esc.throttle_pulse(1500) is None
    drive(esc, t, t + 0.1, 1000)  # the stick at zero: armed
    assert esc.mode is EscMode.ARMED and esc.throttle_pulse(1300) == 1300 and esc.programmed == []


def test_powered_up_at_full_throttle_it_learns_high_then_low_and_keeps_them():
    esc = EmulatedEsc()
    t = drive(esc, 0.0, 1.2, 2000)  # held past the 1.0 s acknowledgement
    assert esc.mode is EscMode.PROGRAM_LOW and esc.throttle_pulse(2000) is None
    t = drive(esc, t, t + 0.3, 1000)
    assert esc.programmed == []  # the low pulse is not held long enough yet
    t = drive(esc, t, t + 0.4, 1000)
    assert [(p.low_us, p.high_us) for p in esc.programmed] == [(1000, 2000)]
    assert esc.mode is EscMode.ARMED
    drive(esc, t, t + 0.1, None, powered=False)  # a power cycle keeps what it learned
    drive(esc, t + 0.2, t + 0.4, 1000)
    assert (esc.low_us, esc.high_us, esc.mode) == (1000, 2000, EscMode.ARMED)


@pytest.mark.parametrize(
    ("high_s", "then", "why"),
    [
        (0.6, [(0.6, 1000)], "the high pulse left before the acknowledgement"),
        (1.2, [(0.2, 1000), (0.1, None)], "the pulses stopped before the low was accepted"),
        (1.2, [(0.2, 1000), (0.1, "off")], "the supply was cut before the low was accepted"),
        (1.2, [(0.8, 1700)], "the low is not far enough below the high"),
    ],
)
def test_interrupted_programming_teaches_nothing(high_s, then, why):
    esc = EmulatedEsc()
    t = drive(esc, 0.0, high_s, 1950)
    for seconds, pulse in then:
        t = drive(esc, t, t + seconds, None if pulse == "off" else pulse, powered=pulse != "off")
    assert esc.programmed == [], why
    assert (esc.low_us, esc.high_us) == (1100.0, 1900.0)


def test_the_first_pulse_decides_programming_relative_to_the_present_endpoints():
    esc = EmulatedEsc(EscParams(factory_low_us=1000.0, factory_high_us=2000.0))
    drive(esc, 0.0, 0.2, 1740)  # 74 % of 1000..2000: not a programming request
    assert esc.mode is EscMode.WAITING
    esc2 = EmulatedEsc(EscParams(factory_low_us=1000.0, factory_high_us=2000.0))
    drive(esc2, 0.0, 0.2, 1760)
    assert esc2.mode is EscMode.PROGRAM_HIGH


def test_replay_follows_frames_gaps_and_the_supply_switch():
    frames = [(0.02 * k, (1500, 1000)) for k in range(50)]  # armed at minimum
    t = 1.0
    frames += [(t + 0.02 * k, (1500, 1950)) for k in range(100)]  # high, but the ESC is already armed
    esc = replay_esc(frames, channel=1)
    assert esc.mode is EscMode.ARMED and esc.programmed == []
    # the same pulses with the supply cut from 1.0 to 1.3 s: it powers up at full throttle and learns
    t = 3.0
    frames += [(t + 0.02 * k, (1500, 1050)) for k in range(50)]
    esc = replay_esc(frames, channel=1, supply_cut=[(1.0, True), (1.3, False)])
    assert [(p.low_us, p.high_us) for p in esc.programmed] == [(1050, 1950)]
    # a gap in the frames (a reset) while learning the low endpoint: nothing is taught
    broken = [f for f in frames if not 3.1 <= f[0] < 3.3]
    esc = replay_esc(broken, channel=1, supply_cut=[(1.0, True), (1.3, False)], gap_s=0.06)
    assert esc.programmed == []
