"""The board's ``Telemetry`` and ``UnitState`` built by their slots
(``firmware_sim.board.telemetry.telemetry``, ``UnitModel.state``: ``protocol.compiled.fast_constructor``,
issue 29) against the keyword constructors they replaced (``telemetry_reference``,
``UnitModel.state_reference``): the same message field by field, every float by its bytes (±0, the wire's
limits and just past them, NaN and ±inf clamped to 0), and the same frame on the wire or the same error
for a field out of range. A field out of its place in the slots (two swapped) fails the second test."""

from __future__ import annotations

import dataclasses
import math
import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.board.power_models import PowerReading
from firmware_sim.board.telemetry import telemetry, telemetry_reference
from hil.timing.clock import LockstepClock
from protocol.errors import HilError
from protocol.frame import BadFrameReason, LinkCounters, decode_frame, encode_frame
from protocol.messages import (
    GIMBAL_ANGLE_LIMIT,
    GIMBAL_RATE_LIMIT,
    ROTOR_SPEED_LIMIT,
    BoardState,
    ControlMode,
    FaultFlag,
    PowerState,
    Telemetry,
    UnitState,
    WatchdogState,
)
from protocol.pulse_widths import FINE_MAX

EDGES = [
    0.0,
    -0.0,
    5e-324,
    -5e-324,
    1e300,
    -1e300,
    math.inf,
    -math.inf,
    math.nan,
    *(s * x for x in (GIMBAL_ANGLE_LIMIT, GIMBAL_RATE_LIMIT, ROTOR_SPEED_LIMIT) for s in (1.0, -1.0)),
    *(math.nextafter(x, math.inf) for x in (GIMBAL_ANGLE_LIMIT, GIMBAL_RATE_LIMIT, ROTOR_SPEED_LIMIT)),
    *(-math.nextafter(x, math.inf) for x in (GIMBAL_ANGLE_LIMIT, GIMBAL_RATE_LIMIT, ROTOR_SPEED_LIMIT)),
]
ANY = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(EDGES), st.floats(-3000, 3000)
)


def _bits(x: object) -> object:
    """A float as its bytes (-0.0 is not 0.0), every NaN as one value; a tuple item by item; else as is."""
    if type(x) is float:
        return "nan" if x != x else struct.pack("<d", x)
    if isinstance(x, tuple):
        return tuple(_bits(v) for v in x)
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return (type(x), _fields(x))
    return (type(x), x)


def _fields(message: object) -> list[object]:
    return [_bits(getattr(message, f.name)) for f in dataclasses.fields(message)]  # type: ignore[arg-type]


def _wire(message: Telemetry) -> object:
    """The frame's bytes and what it decodes to, or the error's type and text."""
    try:
        data = encode_frame(message, 7)
    except HilError as exc:
        return (type(exc), str(exc))
    return data, _fields(decode_frame(data[:-1]).message)


@settings(max_examples=400, deadline=None)
@given(angle=ANY, rate=ANY, speed=ANY, accel=ANY)
def test_a_units_state_by_its_slots_is_its_keyword_state_bit_for_bit(angle, rate, speed, accel):
    """``UnitModel.state`` and ``state_reference`` on a unit the world handed any floats to."""
    board = Board(BoardConfig(n_units=1), LockstepClock(1.0))
    unit = board.units[0]
    unit.follow(angle, rate, speed, 0.5, accel)
    fast, ref = unit.state(), unit.state_reference()
    assert type(fast) is UnitState and type(ref) is UnitState
    assert _fields(fast) == _fields(ref)
    assert fast == ref or any(v != v for v in (fast.gimbal_angle, fast.gimbal_rate, fast.rotor_speed))
    assert board.unit_states() == (ref,)


COUNT = st.one_of(st.integers(0, 2**40), st.sampled_from([0, 2**32 - 1, 2**32, 2**33 + 5]))
WIDTH = st.one_of(st.none(), st.integers(0, 2600), st.sampled_from([0, 2500, 2501, 65535, 65536, -1]))
STATE = st.builds(UnitState, ANY, ANY, ANY)


@settings(max_examples=400, deadline=None)
@given(
    time_ms=st.one_of(st.integers(0, 2**32 - 1), st.sampled_from([0, 2**32 - 1, 2**32])),
    state=st.sampled_from(list(BoardState)),
    mode=st.sampled_from(list(ControlMode)),
    watchdog=st.sampled_from(list(WatchdogState)),
    power_state=st.sampled_from(list(PowerState)),
    faults=st.sampled_from([FaultFlag.NONE, FaultFlag.LINK_LOST | FaultFlag.DEAD_ESC, ~FaultFlag.NONE]),
    link_age_us=st.one_of(st.none(), st.integers(0, 2**40)),
    reading=st.tuples(ANY, ANY, st.one_of(ANY, st.floats(-0.5, 1.5)), ANY, ANY),
    counts=st.tuples(COUNT, COUNT, COUNT),
    outputs=st.lists(WIDTH, max_size=10),
    units=st.lists(STATE, max_size=5),
)
def test_telemetry_by_its_slots_is_the_keyword_message_bit_for_bit(
    time_ms, state, mode, watchdog, power_state, faults, link_age_us, reading, counts, outputs, units
):
    """``telemetry`` and ``telemetry_reference`` give the same fields and, on the wire, the same frame or
    the same error (a width past 16 bits, too many channels or units, a unit's NaN)."""
    power = PowerReading(*reading)
    counters = LinkCounters(frames=counts[0], seq_gaps=counts[2])
    counters.bad[next(iter(BadFrameReason))] = counts[1]
    kwargs = dict(
        time_ms=time_ms,
        state=state,
        mode=mode,
        watchdog=watchdog,
        power_state=power_state,
        faults=faults,
        link_age_us=link_age_us,
        power=power,
        counters=counters,
        outputs=outputs,
        units=tuple(units),
    )
    try:
        ref = telemetry_reference(**kwargs)
    except (ValueError, OverflowError) as exc:  # round() of ±inf SoC: the same error from both
        try:
            telemetry(**kwargs)
        except type(exc) as again:
            assert str(again) == str(exc)
            return
        raise AssertionError(f"the reference raised {exc!r}, the slots did not") from None
    fast = telemetry(**kwargs)
    assert type(fast) is Telemetry
    assert _fields(fast) == _fields(ref)
    assert _wire(fast) == _wire(ref)


def test_a_running_boards_telemetry_is_its_keyword_message():
    """On a board that booted and sends telemetry: the message it builds now, by slots, equals the one
    the keyword constructors build from the same state (fine widths up to ``FINE_MAX`` reported)."""
    clock = LockstepClock(0.0)
    board = Board(BoardConfig(n_units=4), clock)
    for t in (0.05, 0.3, 1.0):
        clock.set(t)
        board.step()
    board.targets = (0, FINE_MAX, None, 512 * 1500, 1, 255, 256, None)
    t = board._t_us
    last_rx = board.commands.last_rx_us
    kwargs = dict(
        time_ms=0,
        state=board.state,
        mode=board.mode,
        watchdog=board.watchdog_state,
        power_state=board.power_state,
        faults=board.fault_flags(),
        link_age_us=None if last_rx is None else t - last_rx,
        power=board.power,
        counters=board.link.deframer.counters,
        outputs=board.reported_outputs(),
    )
    fast = telemetry(**kwargs, units=board.unit_states())
    ref = telemetry_reference(**kwargs, units=tuple(u.state_reference() for u in board.units))
    assert _fields(fast) == _fields(ref)
    assert _wire(fast) == _wire(ref)
