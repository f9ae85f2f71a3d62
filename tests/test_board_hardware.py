"""The board's fused physics step (``firmware_sim.board.hardware.step_hardware``, called by
``Board._physics``) against the separate calls it replaced (``Board._physics_reference``: each unit's
``UnitModel.step``, ``Battery.discharge``, ``power.solve_supply``): on two boards set up alike with
absurd-but-valid states (NaN, ±0, huge speeds, a voltage of zero or below, ESCs in every mode, dead
channels, sags, followed and free units), one step of each leaves the very same floats everywhere."""

from __future__ import annotations

import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.board.esc import EscMode
from hil.timing.clock import LockstepClock

ANY = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e300, -1e300, 5e-324]),
    st.floats(-3000.0, 3000.0),
)
PULSE = st.one_of(st.none(), st.floats(900.0, 2100.0), st.sampled_from([1000.0, 1100.0, 1900.0]))
UNIT = st.fixed_dictionaries(
    {
        "followed": st.booleans(),
        "angle": ANY,
        "rate": ANY,
        "speed": ANY,
        "accel": ANY,
        "mode": st.sampled_from(list(EscMode)),
        "connected": st.booleans(),
        "rotor_dead_at": st.one_of(st.none(), st.floats(0.0, 2.0)),
        "gimbal_dead_at": st.one_of(st.none(), st.floats(0.0, 2.0)),
        "g_us": PULSE,
        "r_us": PULSE,
    }
)
SUPPLY = st.fixed_dictionaries(
    {
        "battery_v": ANY,
        "battery_a": st.one_of(ANY, st.floats(0.0, 30.0)),
        "soc": st.one_of(st.floats(-0.5, 1.5), st.sampled_from([0.0, -0.0, 1.0])),
        "sag_v": st.one_of(st.just(0.0), st.floats(0.0, 20.0)),
        "extra_ohm": st.one_of(st.just(0.0), st.floats(0.0, 5.0)),
        "sag": st.one_of(
            st.none(), st.tuples(st.floats(0.0, 15.0), st.floats(0.0, 2.0), st.floats(0.0, 1.0))
        ),
        "supply_cut": st.booleans(),
        "dt_us": st.integers(1, 200_000),
    }
)


def _board(units: list[dict], supply: dict) -> Board:
    board = Board(BoardConfig(n_units=len(units)), LockstepClock(1.0))
    outputs: list[float | None] = []
    for i, (unit, u) in enumerate(zip(board.units, units, strict=True)):
        if u["followed"]:
            unit.follow(u["angle"], u["rate"], u["speed"], 0.5, u["accel"])
        else:  # the unit's own model: states it could reach
            unit.gimbal_angle = u["angle"] if abs(u["angle"]) < 10.0 else 0.0
            unit.rotor_speed = u["speed"] if abs(u["speed"]) < 2000.0 else 0.0
        unit.esc.mode = u["mode"]
        unit.esc_connected = u["connected"]
        if u["gimbal_dead_at"] is not None:
            board.faults.dead_esc(2 * i, at=u["gimbal_dead_at"])
        if u["rotor_dead_at"] is not None:
            board.faults.dead_esc(2 * i + 1, at=u["rotor_dead_at"])
        outputs += [u["g_us"], u["r_us"]]
    board.outputs = tuple(outputs)
    p = board.power
    p.battery_v, p.battery_a = supply["battery_v"], supply["battery_a"]
    board.battery.soc = supply["soc"]
    board.battery.sag_v, board.battery.extra_resistance_ohm = supply["sag_v"], supply["extra_ohm"]
    if supply["sag"] is not None:
        drop, ohm, ramp = supply["sag"]
        board.faults.sag(drop, ohm, ramp, at=0.9)
    board.esc_calibration.supply_cut = supply["supply_cut"]
    return board


def _bits(x: object) -> object:
    """A float as its bytes (-0.0 differs from 0.0), every NaN as one value (NaN equals itself; its sign
    and payload mean nothing, and CPython's specialised float operations, which take over after a few
    calls, may give a NaN of the other sign than the generic ones: the same inputs drew a positive NaN on
    one call and a negative one on the next); anything else as it is."""
    if type(x) is float:
        return "nan" if x != x else struct.pack("<d", x)
    return x


def _hardware(board: Board) -> list[object]:
    out: list[object] = [board.drive_epoch, board._phys_us]
    for unit in board.units:
        esc = unit.esc
        out += [
            unit.rotor_speed,
            unit.rotor_accel,
            unit.gimbal_angle,
            unit.gimbal_rate,
            unit.rotor_dead,
            unit.gimbal_dead,
            unit.rotor_driven,
            unit.gimbal_driven,
            esc.mode,
            esc.low_us,
            esc.high_us,
            esc._since,
            esc._high_seen,
            esc._low_seen,
            list(esc.programmed),
        ]
    b = board.battery
    out += [b.soc, b.sag_v, b.extra_resistance_ohm, b._segment]
    p = board.power
    out += [p.battery_v, p.battery_a, p.soc, p.ubec_v, p.ubec_a, p.ubec_overcurrent]
    return [_bits(x) for x in out]


def _raised(step: object, t: int) -> type[BaseException] | None:
    try:
        step(t)  # type: ignore[operator]
    except (ArithmeticError, ValueError) as e:  # a cube past the floats; a NaN voltage into a map
        return type(e)
    return None


@settings(max_examples=500, deadline=None)
@given(units=st.lists(UNIT, min_size=1, max_size=5), supply=SUPPLY, steps=st.integers(1, 3))
def test_the_fused_physics_step_is_the_separate_calls_bit_for_bit(units, supply, steps):
    """Each step of ``_physics`` leaves units, ESCs, battery and reading as ``_physics_reference`` does."""
    new, ref = _board(units, supply), _board(units, supply)
    assert _hardware(new) == _hardware(ref)
    t = new._phys_us
    for _ in range(steps):
        t += supply["dt_us"]
        raised = _raised(new._physics, t)
        assert raised == _raised(ref._physics_reference, t)  # the same error from both, if any
        if raised is not None:
            return
        assert _hardware(new) == _hardware(ref)
    new._physics(t)  # no time passed: nothing moves
    assert _hardware(new) == _hardware(ref)
