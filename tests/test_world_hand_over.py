"""The world's hand-over of unit states to the board as plain floats (``World._listed_units``,
``_wrap_angles``, ``Board.hand_over``, ``UnitModel.follow``) against the UnitState path it replaced at
every board event (``World.unit_states``, ``Board.set_unit_states``, ``UnitModel.override``): the same
wrapped angles, the same unit state on the board, the same telemetry."""

from __future__ import annotations

import math
import struct

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.world.world import _wrap, _wrap_angles
from protocol.messages import UnitState

ANGLES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=False),  # the plant stops on a state not finite
    st.floats(-10.0, 10.0),
    st.sampled_from(
        [math.pi, -math.pi, math.nextafter(math.pi, 4.0), math.nextafter(-math.pi, -4.0), 0.0, -0.0]
    ),
)


def _world():
    from firmware_sim.world import World
    from hil.scenario import load_scenario
    from hil.timing.clock import LockstepClock

    scenario = load_scenario("cubesat-1u")
    board = Board(BoardConfig(n_units=scenario.n_units), LockstepClock())
    return World(scenario, board)


WORLD = _world()


@settings(max_examples=300, deadline=None)
@given(st.lists(ANGLES, min_size=1, max_size=8))
def test_angles_are_wrapped_as_the_telemetry_wrap_does(angles):
    """Angles within ±π are their own IEEE remainder: only the others are wrapped, by :func:`_wrap`; the
    rest of the row is left alone, and a second wrap changes nothing."""
    n = len(angles)
    values = list(angles) + [1.0, 2.0]
    _wrap_angles(values, n)
    want = [_wrap(a) for a in angles]
    assert np.array_equal(values[:n], want, equal_nan=True)
    assert [math.copysign(1.0, v) for v in values[:n]] == [math.copysign(1.0, w) for w in want]
    assert values[n:] == [1.0, 2.0]
    again = list(values)
    _wrap_angles(again, n)
    assert np.array_equal(again, values, equal_nan=True)


def test_the_listed_rows_are_the_reference_unit_states_once_wrapped():
    """A row the world lists, wrapped, is what :meth:`World.unit_states` gives for it."""
    world, n = WORLD, WORLD.n
    rows = np.zeros((3, world.layout.size))
    cols = world._unit_columns
    rows[:, cols] = np.linspace(-9.0, 9.0, 3 * 3 * n).reshape(3, 3 * n)
    for row, values in zip(rows, world._listed_units(rows[:, cols]), strict=True):
        _wrap_angles(values, n)
        states = world.unit_states(row)
        assert values == [s.gimbal_angle for s in states] + [s.gimbal_rate for s in states] + [
            s.rotor_speed for s in states
        ]
        assert all(type(v) is float for v in values)


FLOATS = st.floats(-500.0, 500.0)
STATES = st.tuples(FLOATS, FLOATS, FLOATS)


@settings(max_examples=100, deadline=None)
@given(
    st.lists(st.tuples(STATES, st.one_of(st.none(), FLOATS), st.floats(0.0, 0.01)), min_size=1, max_size=6)
)
def test_follow_keeps_the_same_unit_state_as_override(hand_overs):
    """Each hand-over as floats leaves a unit as a UnitState override would: state, acceleration."""
    a, b = (Board(BoardConfig(n_units=1)).units[0] for _ in range(2))
    t = 1.0
    for (angle, rate, speed), accel, dt in hand_overs:
        t += dt
        a.override(UnitState(angle, rate, speed), t, accel)
        b.follow(angle, rate, speed, t, accel)
        assert (a.state(), a.rotor_accel, a.external) == (b.state(), b.rotor_accel, b.external)
    a.override(None, t + 1.0)
    assert not a.external


def test_hand_over_gives_the_board_what_set_unit_states_gave():
    """A board handed the floats reports the same units (telemetry's UnitState) as one handed UnitStates."""
    boards = [Board(BoardConfig()) for _ in range(2)]
    n = boards[0].config.n_units
    states = [UnitState(0.1 * i, -0.01 * i, 100.0 + i) for i in range(n)]
    values = (
        [s.gimbal_angle for s in states] + [s.gimbal_rate for s in states] + [s.rotor_speed for s in states]
    )
    accel = [float(i) for i in range(n)]
    boards[0].set_unit_states(states, at=0.5, rotor_accel=accel)
    boards[1].hand_over(values, 0.5, accel)
    assert boards[0].unit_states() == boards[1].unit_states() == tuple(states)
    assert [u.rotor_accel for u in boards[0].units] == [u.rotor_accel for u in boards[1].units] == accel


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.lists(st.tuples(ANGLES, ANGLES, ANGLES, st.one_of(st.none(), ANGLES)), min_size=4, max_size=4),
            st.floats(0.0, 0.01),
        ),
        min_size=1,
        max_size=4,
    )
)
def test_follow_all_leaves_every_unit_as_its_own_follow_does(hand_overs):
    """``follow_all`` (``UnitModel.follow`` spelt out per unit) against ``follow`` called unit by unit: the
    same floats (NaN, ±0 kept), the same hand-over time, an unmeasured acceleration worked out alike."""
    from firmware_sim.board.actuators import follow_all

    a, b = (Board(BoardConfig(n_units=4)).units for _ in range(2))
    t = 1.0
    for units, dt in hand_overs:
        t += dt
        values = [u[0] for u in units] + [u[1] for u in units] + [u[2] for u in units]
        accel = [u[3] for u in units]
        follow_all(a, values, t, accel)
        for i, unit in enumerate(b):
            unit.follow(values[i], values[4 + i], values[8 + i], t, accel[i])
        for x, y in zip(a, b, strict=True):
            got = (x.gimbal_angle, x.gimbal_rate, x.rotor_speed, x.rotor_accel, x._external_t)
            want = (y.gimbal_angle, y.gimbal_rate, y.rotor_speed, y.rotor_accel, y._external_t)
            assert [struct.pack("<d", v) for v in got] == [struct.pack("<d", v) for v in want]


def test_rotor_accelerations_are_the_batchs_speed_differences_over_the_step():
    """Worked out per row handed over, they are np.diff of the batch's rotor speeds over the plant step
    (the numpy pass they replace): rotors coasting down from 400 rad/s, undriven."""
    world = _world()
    n = world.n
    world.state = world.plant.state(
        R=world.scenario.slew.R0,
        gimbal_angle=world.scenario.slew.gimbal_angle0,
        rotor_rate=np.full(n, 400.0),
        t=0.0,
    )
    speeds = world._unit_columns[2 * n :]
    checked = 0
    for j in range(1, 40):
        world.advance_to(world.t0 + j * 0.005)
        rows = world._rows[: world._head + 1]
        want = np.diff(rows[:, speeds], axis=0) / world.step_s
        got = [world._rotor_accel(k) for k in range(1, world._head + 1)]
        assert np.array_equal(np.reshape(got, want.shape), want)
        checked += len(got)
    assert checked > 20 and np.all(want < 0.0)  # coasting: every rotor slows down
