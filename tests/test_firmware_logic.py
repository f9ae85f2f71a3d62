"""The firmware's sans-IO logic in C (state.c, power.c, link.c, config.c) against its Python references:
firmware_sim.board.state.transition, firmware_sim.board.power_models.PowerManager,
protocol.calibration.Reassembler, protocol.reliable's receiver rules, and the EEPROM configuration block of
firmware_sim.avr.eeprom."""

from __future__ import annotations

import dataclasses
import math
import struct

import hypothesis.strategies as st
import pytest
from hypothesis import example, given, settings

from firmware_sim.avr import eeprom
from firmware_sim.avr.hostlib import CAnswerCache, CPowerManager, CReassembler, config_parse, state_transition
from firmware_sim.board.config import BoardConfig, PowerThresholds
from firmware_sim.board.power_models import PowerManager
from firmware_sim.board.state import Event, transition
from protocol.calibration import Reassembler, fragment
from protocol.crc import crc16_ccitt_false
from protocol.errors import CalibrationError, ConfigError
from protocol.messages import Arm, BoardState, ControlMode, Disarm, Flags, NackReason, SetMode, encode_payload

# C event codes (state.h) in the order of the enum there
C_EVENTS = {
    Event.RESET: 0,
    Event.HELLO: 1,
    Event.ARM: 2,
    Event.DISARM: 3,
    Event.SET_MODE: 4,
    Event.LINK_LOST: 5,
}


@pytest.mark.firmware
@pytest.mark.parametrize("state", list(BoardState))
@pytest.mark.parametrize("event", list(Event))
@pytest.mark.parametrize("power_ok", [True, False])
def test_state_transitions_match_firmware_sim(state, event, power_ok):
    want = transition(state, event, power_ok=power_ok)
    got = state_transition(int(state), C_EVENTS[event], power_ok)
    assert got == (int(want.state), 0 if want.refused is None else int(want.refused))


# --------------------------------------------------------------------------- power manager
THRESHOLDS = PowerThresholds()
LEVELS = (THRESHOLDS.warn_v_cell, THRESHOLDS.limit_v_cell, THRESHOLDS.shed_v_cell)
EDGES = LEVELS + tuple(v + THRESHOLDS.hysteresis_v_cell for v in LEVELS)


def _ambiguous(v_cell: float) -> bool:
    """Within float32 rounding of a stage boundary: the two implementations may round either way."""
    return any(abs(v_cell - e) < 1e-4 for e in EDGES)


@pytest.mark.firmware
@settings(max_examples=200, deadline=None)
@given(
    volts=st.lists(st.floats(8.0, 13.0), min_size=1, max_size=60),
    tau=st.sampled_from([0.0, 0.01, 0.05, 0.5]),
)
def test_power_stages_match_firmware_sim(volts, tau):
    dt, cells = 0.005, 3
    t = dataclasses.replace(THRESHOLDS, filter_time_constant_s=tau)
    py = PowerManager(t, cells)
    alpha = 1.0 - math.exp(-dt / tau) if tau > 0 else 1.0
    c = CPowerManager(t.warn_v_cell, t.limit_v_cell, t.shed_v_cell, t.hysteresis_v_cell, alpha, cells)
    for k, v in enumerate(volts):
        want = py.update(v, dt if k else 0.0)
        got = c.update(v)
        assert math.isclose(c.state.filtered_v_cell, py.filtered_v_cell, rel_tol=1e-5)
        if _ambiguous(py.filtered_v_cell):
            break  # from here on the hysteresis state may legitimately differ by one rounding
        assert got == int(want), f"step {k}: {v} V"


# --------------------------------------------------------------------------- calibration reassembly
C_DONE, C_PENDING = 1, 0


def _c_feed(c: CReassembler, m) -> int:
    return c.feed(m.unit, m.transfer_id, m.index, m.count, m.total_len, m.set_crc, m.chunk)


@pytest.mark.firmware
@settings(max_examples=150, deadline=None)
@given(
    data=st.binary(min_size=1, max_size=700),
    order=st.randoms(use_true_random=False),
    repeats=st.integers(0, 3),
    corrupt=st.sampled_from(["none", "chunk", "count", "crc", "index"]),
)
def test_reassembly_matches_the_python_reassembler(data, order, repeats, corrupt):
    parts = fragment(2, 7, data)
    parts += [order.choice(parts) for _ in range(repeats)]
    order.shuffle(parts)
    if corrupt != "none":
        k = order.randrange(len(parts))
        m = parts[k]
        parts[k] = {
            "chunk": dataclasses.replace(m, chunk=m.chunk[:-1] + bytes([m.chunk[-1] ^ 1])),
            "count": dataclasses.replace(m, count=min(m.count + 1, 255)),
            "crc": dataclasses.replace(m, set_crc=m.set_crc ^ 0x0101),
            "index": dataclasses.replace(m, index=m.count),
        }[corrupt]
    py, c = Reassembler(max_len=798), CReassembler(798)
    for m in parts:
        try:
            done = py.feed(m)
            want = C_PENDING if done is None else C_DONE
        except CalibrationError:
            want = -1
        got = _c_feed(c, m)
        assert (got if got in (C_PENDING, C_DONE) else -1) == want, m
        if want == C_DONE:
            assert c.data(len(data)) == data == done[1]


@pytest.mark.firmware
def test_reassembly_refuses_a_set_larger_than_the_board_holds():
    (m,) = fragment(0, 1, bytes(150))
    assert _c_feed(CReassembler(100), m) not in (C_PENDING, C_DONE)
    assert _c_feed(CReassembler(798), m) == C_DONE


# --------------------------------------------------------------------------- answer cache
@pytest.mark.firmware
def test_a_retransmitted_command_gets_the_remembered_answer_without_running_again():
    c = CAnswerCache()
    arm, payload = 0x10, b""
    assert c.lookup(arm, 5, int(Flags.ACK_REQUESTED), payload) is None
    c.remember(arm, 5, payload, 0)
    assert c.lookup(arm, 5, int(Flags.ACK_REQUESTED | Flags.RETRANSMIT), payload) == 0
    assert c.lookup(arm, 5, int(Flags.ACK_REQUESTED), payload) is None  # not a retry: a new command
    c.remember(0x12, 6, b"\x01", int(NackReason.BAD_STATE))
    assert c.lookup(0x12, 6, int(Flags.RETRANSMIT), b"\x01") == int(NackReason.BAD_STATE)
    assert c.lookup(0x12, 6, int(Flags.RETRANSMIT), b"\x00") is None  # same key, other content
    for seq in range(100, 132):  # 32 newer answers push the oldest out
        c.remember(0x11, seq, b"", 0)
    assert c.lookup(arm, 5, int(Flags.RETRANSMIT), payload) is None


@pytest.mark.firmware
@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(  # three message ids, two contents of one
                [Arm(), Disarm(), SetMode(mode=ControlMode.SETPOINT), SetMode(mode=ControlMode.RAW_PULSES)]
            ),
            st.one_of(st.integers(0, 3), st.none()),  # one of a few sequence numbers, or the next fresh one
            st.booleans(),  # a retransmission (looked up) or a new command (remembered)
        ),
        max_size=200,
    )
)
@example(
    [(Arm(), 0, False)]
    + [(Disarm(), None, False)] * 10
    + [(Arm(), 0, False)]
    + [(Disarm(), None, False)] * 25
    + [(Arm(), 0, True)]
)
def test_the_answer_cache_keeps_the_last_32_answers_in_the_order_given_as_the_emulator_does(ops):
    """Any run of commands whose keys come back (the host's sequence numbers wrap), among fresh ones that
    push old answers out: the C cache answers a retransmission exactly when the emulator's ordered dict
    does, with the same answer. The C ring once left a key answered again in its old slot — overwritten up
    to 31 answers early, a late Arm carried out again (the @example;
    tests/test_firmware_answer_cache_order.py)."""
    from firmware_sim.board.link import BoardLink
    from protocol.frame import Frame

    c = CAnswerCache()
    py = BoardLink(rx_capacity=64, tx_capacity=64)
    fresh = 4
    for k, (message, reused, retransmit) in enumerate(ops):
        if reused is None:
            seq, fresh = fresh, 4 + (fresh - 3) % 252  # 4..255, then round again
        else:
            seq = reused
        flags = Flags.ACK_REQUESTED | (Flags.RETRANSMIT if retransmit else Flags.NONE)
        frame = Frame(message=message, seq=seq, flags=flags)
        msg_id, payload = frame.msg_id, encode_payload(message)
        want = py.cached_answer(frame)
        got = c.lookup(msg_id, seq, int(flags), payload)
        assert got == want, (k, msg_id, seq, payload)
        if got is None:
            answer = k % 7  # an Ack (0) or a Nack reason: what was answered
            py.remember_answer(frame, answer)
            c.remember(msg_id, seq, payload, answer)


# --------------------------------------------------------------------------- EEPROM configuration block
@pytest.mark.firmware
def test_a_configuration_block_reaches_the_firmware_field_by_field():
    base = BoardConfig()
    cfg = base.replace(
        n_units=3,
        frame_rate_hz=200.0,
        telemetry_rate_hz=40.0,
        link_timeout_s=0.4,
        mcu_watchdog_s=1.5,
        rotor_safe_us=1100,
        esc_supply_switch=True,
        identity=dataclasses.replace(base.identity, serial="LAB-07"),
    )
    status, got, _ = config_parse(eeprom.config_block(cfg, baud=250000))
    assert status == 0
    assert (got["n_units"], got["frame_rate_hz"], got["telemetry_rate_hz"]) == (3, 200.0, 40.0)
    assert (got["link_timeout_ms"], got["mcu_watchdog_ms"], got["rotor_safe_us"]) == (400, 1500, 1100)
    assert (got["serial"], got["baud"], got["cells"]) == ("LAB-07", 250000, 3)
    assert got["esc_supply_switch"] == 1


@pytest.mark.firmware
def test_without_a_valid_block_the_firmware_runs_on_boardconfig_defaults():
    defaults = BoardConfig()
    block = eeprom.config_block(defaults)
    for image, status in ((b"\xff" * eeprom.CONFIG_SIZE, 1), (block[:-1] + bytes([block[-1] ^ 1]), 2)):
        got_status, got, _ = config_parse(image)
        assert got_status == status
        assert got["n_units"] == defaults.n_units and got["frame_rate_hz"] == defaults.frame_rate_hz
        assert got["link_timeout_ms"] == round(defaults.link_timeout_s * 1000)
        assert math.isclose(got["warn_v_cell"], defaults.power.thresholds.warn_v_cell, rel_tol=1e-6)


@pytest.mark.firmware
def test_a_block_with_a_value_out_of_range_is_refused_and_names_it():
    body = bytearray(eeprom.config_block(BoardConfig())[:-2])
    body[eeprom.field_offsets()["n_units"]] = 7  # more units than the hardware has channels for
    status, got, problem = config_parse(bytes(body) + struct.pack("<H", crc16_ccitt_false(bytes(body))))
    assert status == 3 and got["n_units"] == BoardConfig().n_units and problem == 2  # "n_units"


@pytest.mark.firmware
@pytest.mark.parametrize("watchdog_s", [0.015, 0.05, 0.099, 0.1, 8.0])
def test_the_mcu_watchdogs_floor_is_the_same_in_the_firmware_and_the_emulator(watchdog_s):
    """Below ``MCU_WATCHDOG_MIN_S`` (0.1 s) both refuse it: the firmware's longest main-loop pass must fit
    (tests/test_firmware_watchdog_floor.py)."""
    from firmware_sim.board.config import MCU_WATCHDOG_MIN_S

    takes = MCU_WATCHDOG_MIN_S <= watchdog_s <= 8.0
    if takes:
        BoardConfig(mcu_watchdog_s=watchdog_s).validate()
    else:
        with pytest.raises(ConfigError, match="mcu_watchdog_s"):
            BoardConfig(mcu_watchdog_s=watchdog_s).validate()
    body = bytearray(eeprom.config_block(BoardConfig())[:-2])
    offset = eeprom.field_offsets()["mcu_watchdog_s"]
    body[offset : offset + 4] = struct.pack("<f", watchdog_s)
    status, got, _ = config_parse(bytes(body) + struct.pack("<H", crc16_ccitt_false(bytes(body))))
    assert (status == 0) is takes
    if takes:
        assert got["mcu_watchdog_ms"] == round(watchdog_s * 1000)


def test_the_image_builder_refuses_what_the_hardware_cannot_do():
    with pytest.raises(ConfigError, match="n_units"):
        eeprom.config_block(BoardConfig(n_units=7))
    with pytest.raises(ConfigError, match="ppm"):
        eeprom.config_block(BoardConfig(n_units=5, ppm=True))
    with pytest.raises(ConfigError, match="baud"):
        eeprom.config_block(BoardConfig(), baud=12)
    assert 4 * eeprom.cal_slot_size(4) + eeprom.CAL_BASE <= eeprom.EEPROM_SIZE
    assert eeprom.cal_slot_size(6) * 6 + eeprom.CAL_BASE <= eeprom.EEPROM_SIZE
