"""The emulated board's ESC endpoint procedure in lockstep: the operator's supply on a board without a
switch, the guards and aborts the conformance suite does not reach, and bench units whose ESCs behave
differently until programmed. (Both targets through a pty: tests/conformance/test_esc_calibration.py.)"""

from __future__ import annotations

import dataclasses

import pytest
from conformance.host import heartbeat, lockstep

from firmware_sim.board.config import BoardConfig
from firmware_sim.board.esc import EscMode
from hil.calibration.generate import bench_units
from protocol.messages import (
    ESC_CALIBRATION_CONFIRM,
    Ack,
    Arm,
    BoardState,
    ControlMode,
    Disarm,
    EscCalAbort,
    EscCalibrate,
    EscCalibrationStatus,
    EscCalPhase,
    EscCalStep,
    FaultFlag,
    Log,
    Nack,
    NackReason,
    RawPulses,
    SetMode,
    Telemetry,
)

MANUAL = BoardConfig(n_units=2, frame_rate_hz=100.0, telemetry_rate_hz=20.0)
SWITCHED = dataclasses.replace(MANUAL, esc_supply_switch=True)


def teach(unit=1, step=EscCalStep.START, confirm=ESC_CALIBRATION_CONFIRM, **kw):
    fields = {"low_us": 1000, "high_us": 2000, "supply_off_ms": 300, "high_ms": 1500, "low_ms": 1000} | kw
    return EscCalibrate(unit=unit, step=step, confirm=confirm, **fields)


def session(cfg):
    board, clock, host = lockstep(cfg)
    host.max_step = 0.005
    host.handshake()
    host.keepalive = heartbeat
    return board, clock, host


def statuses(host):
    return [m for m in host.received if isinstance(m, EscCalibrationStatus)]


def phases(host):
    out = []
    for s in statuses(host):
        if not out or out[-1] is not s.phase:
            out.append(s.phase)
    return out


def refused(answer, reason):
    return isinstance(answer, Nack) and answer.reason == reason


def test_without_a_supply_switch_the_board_asks_for_the_supply_and_waits_for_the_host():
    board, clock, host = session(MANUAL)
    esc = board.units[1].esc
    assert esc.mode is EscMode.ARMED
    assert isinstance(host.request(teach()), Ack)
    host.poll(2.0)  # the operator takes their time: the board holds the high endpoint and waits
    assert phases(host) == [EscCalPhase.WAIT_SUPPLY]
    assert esc.mode is EscMode.OFF and board.outputs[3] == 2000  # disconnected, as asked
    ask = [m for m in host.received if isinstance(m, Log) and "connect the ESC's supply now" in m.text]
    assert ask and ask[0].code == 12
    assert refused(host.request(teach(unit=0, step=EscCalStep.SUPPLY_APPLIED)), NackReason.BAD_STATE)
    assert refused(host.request(teach(step=EscCalStep.SUPPLY_APPLIED, confirm=0)), NackReason.UNCONFIRMED)
    assert isinstance(host.request(teach(step=EscCalStep.SUPPLY_APPLIED)), Ack)
    t_applied = board.last_rx
    host.poll(3.0)
    assert phases(host) == [EscCalPhase.WAIT_SUPPLY, EscCalPhase.HIGH, EscCalPhase.LOW, EscCalPhase.DONE]
    assert [(p.low_us, p.high_us) for p in esc.programmed] == [(1000, 2000)]
    frames = [(f.t, f.widths[3]) for f in board.timeline.frames if f.t >= t_applied]
    t_low = next(t for t, w in frames if w == 1000)
    assert 1.5 - 0.011 <= t_low - t_applied <= 1.5 + 0.011  # high_ms from the host's word, board-timed
    assert board.units[0].esc.mode is EscMode.ARMED and board.units[0].esc.programmed == []


def test_the_supply_wait_runs_out_and_leaves_the_esc_at_minimum():
    board, clock, host = session(MANUAL)
    assert isinstance(host.request(teach()), Ack)
    host.poll(60.5)
    assert phases(host) == [EscCalPhase.WAIT_SUPPLY, EscCalPhase.ABORTED]
    assert statuses(host)[-1].abort == EscCalAbort.SUPPLY_TIMEOUT
    assert board.outputs[3] == MANUAL.rotor_safe_us and board.mode is ControlMode.SETPOINT
    assert board.units[1].esc.mode is EscMode.ARMED and board.units[1].esc.programmed == []


def test_a_new_session_and_load_shedding_abort_it_and_shedding_refuses_it():
    board, clock, host = session(SWITCHED)
    assert isinstance(host.request(teach(supply_off_ms=2000)), Ack)
    host.poll(0.5)
    assert not board.units[0].esc.powered  # one switch cuts every ESC's supply
    host.handshake()
    host.poll(0.1)
    assert statuses(host)[-1].phase == EscCalPhase.ABORTED and statuses(host)[-1].abort == EscCalAbort.HELLO
    assert board.esc_calibration.supply_cut is False and board.outputs[3] == SWITCHED.rotor_safe_us
    host.received.clear()
    assert isinstance(host.request(teach(high_ms=5000)), Ack)
    host.poll(0.5)
    board.faults.sag(drop_v=4.0, at=board.now)  # a 3S pack at 8.6 V: below SHED
    host.poll(1.0)
    assert statuses(host)[-1].abort == EscCalAbort.POWER
    assert refused(host.request(teach()), NackReason.POWER)
    assert board.units[1].esc.programmed == []


def test_the_board_refuses_what_it_cannot_run_safely():
    board, clock, host = lockstep(SWITCHED)
    assert refused(host.request(teach()), NackReason.BAD_STATE)  # BOOT: no session yet
    host.handshake()
    host.keepalive = heartbeat
    assert refused(host.request(teach(high_us=1300)), NackReason.OUT_OF_RANGE)  # endpoints 300 us apart
    assert refused(host.request(teach(supply_off_ms=50)), NackReason.OUT_OF_RANGE)  # too short a power cut
    assert refused(host.request(teach(unit=2)), NackReason.OUT_OF_RANGE)
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = None  # link lost while armed: FAILSAFE
    host.poll(0.5)
    assert board.state is BoardState.FAILSAFE
    assert refused(host.request(teach()), NackReason.BAD_STATE)
    host.keepalive = heartbeat
    host.handshake()
    assert isinstance(host.request(teach()), Ack)
    assert refused(host.request(SetMode(mode=ControlMode.RAW_PULSES)), NackReason.BUSY)
    assert board.units[1].esc.programmed == []


def _steady_speed(board, clock, host, unit, width, seconds=1.5):
    """Raw ``width`` on ``unit``'s rotor for ``seconds``; the speed telemetry reports at the end."""
    raw = list(board.reported_outputs())
    raw[2 * unit + 1] = width
    host.keepalive = lambda: RawPulses(pulses_us=tuple(raw))
    host.poll(seconds)
    tel = host.wait_type(Telemetry, 1.0)
    return tel.units[unit].rotor_speed, tel.battery_mv / 1000.0


def test_a_bench_unit_runs_on_its_escs_endpoints_factory_until_programmed():
    cfg = dataclasses.replace(SWITCHED, unit_spread_seed=5)
    board, clock, host = session(cfg)
    truth = bench_units(2, 5)[0].motor
    assert board.units[0].truth.motor == truth  # the unit is the seed's bench unit, not its calibration
    assert isinstance(host.request(SetMode(mode=ControlMode.RAW_PULSES)), Ack)
    assert isinstance(host.request(Arm()), Ack)
    w_factory, v = _steady_speed(board, clock, host, 0, 1950)
    top = truth.kv_rad_s_per_v * v
    assert w_factory == pytest.approx(top, rel=0.01)  # factory high 1900 us: full throttle already
    assert board.units[0].steady_rotor_speed(1130, v) == 0.0  # factory low 1100 us + the motor's deadband
    host.keepalive = heartbeat
    assert isinstance(host.request(Disarm()), Ack)
    assert isinstance(host.request(teach(unit=0)), Ack)
    host.poll(3.0)
    assert [(p.low_us, p.high_us) for p in board.units[0].esc.programmed] == [(1000, 2000)]
    assert isinstance(host.request(SetMode(mode=ControlMode.RAW_PULSES)), Ack)
    assert isinstance(host.request(Arm()), Ack)
    w_taught, v = _steady_speed(board, clock, host, 0, 1950)
    expected = dataclasses.replace(truth, low_us=1000.0, high_us=2000.0).speed(1950.0, v)
    assert w_taught == pytest.approx(expected, rel=0.01) and w_taught < 0.98 * w_factory
    assert board.units[0].steady_rotor_speed(1130, v) > 20.0


def test_an_esc_being_taught_is_not_reported_dead():
    """Its channel at the high endpoint stands for full speed, yet the ESC turns nothing: unpowered while
    the board waits for its supply, then in its programming mode. That is what the procedure expects; it
    was reported ``ERROR rotor ESC on channel 3 (unit 1) not responding`` in every emulated calibration."""
    board, clock, host = session(MANUAL)
    assert isinstance(host.request(teach()), Ack)
    host.poll(2.0 + MANUAL.dead_esc_detect_s)  # well past the detector's time, at full-speed width
    assert board.outputs[3] == 2000 and board.units[1].rotor_speed == 0.0
    assert isinstance(host.request(teach(step=EscCalStep.SUPPLY_APPLIED)), Ack)
    host.poll(3.0)
    assert phases(host)[-1] is EscCalPhase.DONE
    logs = [m for m in host.received if isinstance(m, Log)]
    assert not [m for m in logs if "not responding" in m.text] and board.dead_esc_detector.found == set()
    assert not any(t.faults & FaultFlag.DEAD_ESC for t in host.received if isinstance(t, Telemetry))
