"""Power thresholds that parse but cannot work: above a full cell, NaN, infinite, negative, out of order.

What a hunt found: ``warn_v_cell``/``limit_v_cell``/``shed_v_cell`` were checked for order only, in the
emulator's ``BoardConfig.validate`` and in the firmware's EEPROM parser alike. A board configured with its
thresholds above a full cell (4.2 V: warn 4.5, limit 4.4, shed 4.3) was accepted and shed its load from
power-on, refusing every ``Arm`` with a full pack; ``warn_v_cell = inf`` passed the order check too, and a
stage whose level plus its hysteresis lay at or above a full cell could never clear once entered. Both
sides now refuse such thresholds, naming the field: the emulator with a ``ConfigError``, the firmware by
running on its defaults and saying so in a ``Log``.
"""

from __future__ import annotations

import math
import struct

import hypothesis.strategies as st
import pytest
from conformance.host import SerialHost, heartbeat, lockstep
from hypothesis import assume, example, given, settings

from firmware_sim.avr import AvrBoard, eeprom
from firmware_sim.avr.hostlib import config_parse
from firmware_sim.board.config import LIPO_OCV_CURVE, BoardConfig, PowerConfig, PowerThresholds
from protocol.crc import crc16_ccitt_false
from protocol.errors import ConfigError
from protocol.messages import Ack, Arm, Log, PowerState, Telemetry

FULL_CELL_V = LIPO_OCV_CURVE[-1][1]
THRESHOLD_FIELDS = ("warn_v_cell", "limit_v_cell", "shed_v_cell", "hysteresis_v_cell")
BAD_THRESHOLD_PROBLEMS = {12: "warn/limit/shed_v_cell", 13: "hysteresis_v_cell"}  # config.c's indices

volts = st.one_of(
    st.floats(-1.0, 6.0),
    st.sampled_from([math.nan, math.inf, -math.inf, -0.0, 0.0, 1e160, -1e160, FULL_CELL_V, 3.5, 3.4, 3.3]),
)
hystereses = st.one_of(st.floats(-0.5, 1.5), st.sampled_from([math.nan, math.inf, -0.0, 0.0, 0.1, 1.0]))


def workable(warn: float, limit: float, shed: float, hysteresis: float) -> bool:
    """What a user expects a board to take: finite, in order, above zero, and every stage able to clear on
    a full pack (its level plus the hysteresis below a full cell)."""
    return (
        all(math.isfinite(v) for v in (warn, limit, shed, hysteresis))
        and warn > limit > shed > 0.0
        and 0.0 <= hysteresis <= 1.0
        and warn + hysteresis < FULL_CELL_V
    )


def configured(warn: float, limit: float, shed: float, hysteresis: float) -> BoardConfig:
    thresholds = PowerThresholds(
        warn_v_cell=warn, limit_v_cell=limit, shed_v_cell=shed, hysteresis_v_cell=hysteresis
    )
    return BoardConfig(n_units=2, telemetry_rate_hz=50.0, power=PowerConfig(thresholds=thresholds))


def float32(value: float) -> float:
    """``value`` as the float32 an EEPROM block holds (beyond its range: infinite)."""
    if math.isfinite(value) and abs(value) > 3.4e38:
        return math.copysign(math.inf, value)
    return struct.unpack("<f", struct.pack("<f", value))[0]


def block_with(**values: float) -> bytes:
    """The default configuration block with ``values`` patched in as float32 and its CRC made good (a
    block another tool wrote: the image builder refuses such thresholds itself)."""
    body = bytearray(eeprom.config_block(BoardConfig())[:-2])
    offsets = eeprom.field_offsets()
    for name, value in values.items():
        struct.pack_into("<f", body, offsets[name], value)
    return bytes(body) + struct.pack("<H", crc16_ccitt_false(bytes(body)))


@settings(max_examples=60, deadline=None)
@given(warn=volts, limit=volts, shed=volts, hysteresis=hystereses)
@example(warn=4.5, limit=4.4, shed=4.3, hysteresis=0.1)  # all above a full cell: shedding from power-on
@example(warn=math.inf, limit=3.4, shed=3.3, hysteresis=0.1)
@example(warn=4.15, limit=3.4, shed=3.3, hysteresis=0.1)  # WARN, once entered, never clears
def test_the_emulator_refuses_thresholds_a_board_cannot_work_with(warn, limit, shed, hysteresis):
    cfg = configured(warn, limit, shed, hysteresis)
    if not workable(warn, limit, shed, hysteresis):
        with pytest.raises(ConfigError) as caught:
            cfg.validate()
        assert caught.value.where.startswith("BoardConfig.power.thresholds"), caught.value
        return
    cfg.validate()
    board, clock, host = lockstep(cfg)
    host.handshake()
    host.poll(0.1)
    first = next(m for m in host.received if isinstance(m, Telemetry))
    if warn + hysteresis < FULL_CELL_V - 0.01:  # clear of the idle board's few mV of sag
        assert first.power == PowerState.NORMAL, first
    # the pack sags below every stage and comes back: the board leaves them all again
    board.faults.sag(drop_v=2.0 * 4.2, at=clock.now(), duration=0.3)
    host.poll(1.0)
    stages = [m.power for m in host.received if isinstance(m, Telemetry)]
    assert PowerState.SHED in stages or PowerState.BROWN_OUT in stages or board.resets, stages
    assert stages[-1] in (PowerState.NORMAL, PowerState.WARN), stages
    if warn + hysteresis < FULL_CELL_V - 0.01:
        assert stages[-1] == PowerState.NORMAL, stages


@pytest.mark.firmware
@settings(max_examples=150, deadline=None)
@given(warn=volts, limit=volts, shed=volts, hysteresis=hystereses)
@example(warn=4.5, limit=4.4, shed=4.3, hysteresis=0.1)
@example(warn=math.inf, limit=3.4, shed=3.3, hysteresis=0.1)
@example(warn=4.15, limit=3.4, shed=3.3, hysteresis=0.1)
def test_the_firmware_takes_the_thresholds_the_emulator_takes_and_no_other(warn, limit, shed, hysteresis):
    as_f32 = [float32(v) for v in (warn, limit, shed, hysteresis)]
    assume(not math.isfinite(as_f32[0] + as_f32[3]) or abs(as_f32[0] + as_f32[3] - FULL_CELL_V) > 1e-4)
    status, got, problem = config_parse(
        block_with(
            warn_v_cell=as_f32[0], limit_v_cell=as_f32[1], shed_v_cell=as_f32[2], hysteresis_v_cell=as_f32[3]
        )
    )
    if workable(*as_f32):
        assert (status, problem) == (0, 0)
        assert math.isclose(got["warn_v_cell"], as_f32[0], rel_tol=1e-6)
    else:
        assert status == 3, (status, problem)  # CONFIG_INVALID: the defaults run
        assert problem in BAD_THRESHOLD_PROBLEMS, problem
        assert math.isclose(got["warn_v_cell"], BoardConfig().power.thresholds.warn_v_cell, rel_tol=1e-6)


@pytest.mark.firmware
def test_a_firmware_board_given_thresholds_above_a_full_cell_runs_on_its_defaults_and_says_so():
    image = bytearray(eeprom.EepromImage(BoardConfig()).to_bytes())
    block = block_with(warn_v_cell=4.5, limit_v_cell=4.4, shed_v_cell=4.3)
    image[: len(block)] = block
    with AvrBoard(BoardConfig(), eeprom_image=bytes(image)) as board:
        host = SerialHost(board.port, clock=board.now)
        host.handshake()
        board.press_reset()  # the boot reports go out at boot: reset with the host listening
        host.handshake()
        host.keepalive = heartbeat
        host.stream(0.3)
        logs = [m.text for m in host.received if isinstance(m, Log)]
        assert any("refused (warn/limit/shed_v_cell)" in text for text in logs), logs
        tel = [m for m in host.received if isinstance(m, Telemetry)]
        assert tel and tel[-1].power == PowerState.NORMAL, tel[-1:]
        assert isinstance(host.request(Arm()), Ack)  # a full pack arms
        host.close()
        board.check()
