"""ESC endpoint programming (``EscCalibrate``) through a real serial port, for every target in TARGETS.

The board runs the procedure on its own clock; what it teaches is judged by an emulated hobby ESC
(:mod:`firmware_sim.board.esc`) that sees the target's real pulses and ESC supply switch: the emulator's own
ESC, or one replaying the C firmware's pins under simavr. Timing is asserted on the board's clock (the
pulse timeline), never on host wall time.
"""

from __future__ import annotations

import pytest

from conformance.host import heartbeat, retry_if_starved
from conformance.targets import uptime_origin
from conformance.test_conformance import MAIN_LOOP_S
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
    Heartbeat,
    Log,
    Nack,
    NackReason,
    ResetCause,
    SetMode,
    Telemetry,
)

UNIT = 1
CHANNEL = 2 * UNIT + 1
LOW, HIGH = 1050, 1950  # distinct from the safe pulse (1000) and the emulated ESC's factory 1100..1900
MS = 0.0015  # the wire carries milliseconds
WAIT = 5.0
"""Slack on every wait for a message (board time, as every wait of the host: ``conformance.host``). The
waits only bound how long a failing test hangs; what is asserted is timed on the board's clock."""


def teach(unit=UNIT, confirm=ESC_CALIBRATION_CONFIRM, supply_off_ms=300, high_ms=1500, low_ms=1000):
    return EscCalibrate(
        unit=unit,
        step=EscCalStep.START,
        confirm=confirm,
        low_us=LOW,
        high_us=HIGH,
        supply_off_ms=supply_off_ms,
        high_ms=high_ms,
        low_ms=low_ms,
    )


def status(host, phase, timeout, since=0):
    """The first status in ``phase`` received from message ``since`` on (already received, e.g. in the
    batch with an Ack, or still to come)."""
    wanted = lambda m: isinstance(m, EscCalibrationStatus) and m.phase == phase  # noqa: E731
    got = next((m for m in host.received[since:] if wanted(m)), None)
    return got or host.wait_for(wanted, timeout, phase.name)


def channel_frames(target, since=None):
    return [(f.t, f.widths[CHANNEL]) for f in target.timeline() if since is None or f.t >= since]


def nack(answer, reason):
    return isinstance(answer, Nack) and answer.reason == reason


def test_esc_mode_refuses_to_start_armed_or_unconfirmed(target, host):
    host.handshake()
    host.keepalive = heartbeat
    assert nack(host.request(teach(confirm=0)), NackReason.UNCONFIRMED)
    assert nack(host.request(teach(confirm=ESC_CALIBRATION_CONFIRM ^ 1)), NackReason.UNCONFIRMED)
    assert nack(host.request(teach(unit=target.spec.n_units)), NackReason.OUT_OF_RANGE)
    assert nack(host.request(SetMode(mode=ControlMode.ESC_CALIBRATION)), NackReason.UNSUPPORTED)
    supply = EscCalibrate(unit=UNIT, step=EscCalStep.SUPPLY_APPLIED, confirm=ESC_CALIBRATION_CONFIRM)
    assert nack(host.request(supply), NackReason.BAD_STATE)  # nothing is waiting for a supply
    assert isinstance(host.request(Arm()), Ack)
    assert nack(host.request(teach()), NackReason.BAD_STATE)
    host.poll(0.2)
    tel = host.wait_type(Telemetry, WAIT * 1.0)
    assert tel.state == BoardState.ARMED and tel.mode == ControlMode.SETPOINT
    assert isinstance(host.request(Disarm()), Ack)
    assert not [m for m in host.received if isinstance(m, EscCalibrationStatus)]
    esc = target.esc(UNIT)
    assert esc.programmed == [] and (esc.low_us, esc.high_us) == (1100.0, 1900.0)  # still factory


def test_esc_mode_programs_the_emulated_escs_endpoints(target, host):
    spec = target.spec
    host.handshake()
    host.keepalive = heartbeat
    assert isinstance(host.request(teach()), Ack)
    high = status(host, EscCalPhase.HIGH, WAIT * 2.0)
    assert high.pulse_us == HIGH and high.supply_on == 1 and high.unit == UNIT
    tel = host.wait_type(Telemetry, WAIT * 1.0)
    assert tel.mode == ControlMode.ESC_CALIBRATION and tel.state == BoardState.DISARMED
    assert tel.pulses_us[CHANNEL] == HIGH
    assert all(w == spec.rotor_safe_us for i, w in enumerate(tel.pulses_us) if i % 2 and i != CHANNEL)
    assert nack(host.request(Arm()), NackReason.BUSY)
    assert nack(host.request(teach()), NackReason.BUSY)
    status(host, EscCalPhase.DONE, WAIT * 4.0)
    done_log = lambda m: isinstance(m, Log) and m.code == 12 and "done" in m.text  # noqa: E731
    if not any(done_log(m) for m in host.received):  # it follows the status, in its batch or later
        host.wait_for(done_log, 1.0, "the Log of the finished procedure")
    got = host.received
    phases = [m.phase for m in got if isinstance(m, EscCalibrationStatus)]
    firsts = [p for i, p in enumerate(phases) if i == 0 or phases[i - 1] != p]
    assert firsts == [EscCalPhase.SUPPLY_OFF, EscCalPhase.HIGH, EscCalPhase.LOW, EscCalPhase.DONE]
    off = next(m for m in got if isinstance(m, EscCalibrationStatus) and m.phase == EscCalPhase.SUPPLY_OFF)
    assert off.supply_on == 0 and off.pulse_us == HIGH
    host.poll(0.2)
    assert host.wait_type(Telemetry, WAIT * 1.0).mode == ControlMode.SETPOINT
    # The board timed it: high_us for supply_off + high_ms, low_us for low_ms, then the safe pulse.
    frames = channel_frames(target)
    t_high = next(t for t, w in frames if w == HIGH)
    t_low = next(t for t, w in frames if t > t_high and w == LOW)
    t_safe = next(t for t, w in frames if t > t_low and w == spec.rotor_safe_us)
    frame = 1.0 / spec.frame_rate_hz
    assert all(w == HIGH for t, w in frames if t_high <= t < t_low)
    assert all(w == LOW for t, w in frames if t_low <= t < t_safe)
    assert 0.3 + 1.5 - frame - MS <= t_low - t_high <= 0.3 + 1.5 + frame + MAIN_LOOP_S
    assert 1.0 - frame - MAIN_LOOP_S <= t_safe - t_low <= 1.0 + frame + MAIN_LOOP_S
    esc = target.esc(UNIT)
    assert [(p.low_us, p.high_us) for p in esc.programmed] == [(LOW, HIGH)]
    assert (esc.low_us, esc.high_us) == (LOW, HIGH) and esc.mode.value == "armed"
    other = target.esc(0)  # one switch cuts every ESC: the others came back up at minimum and armed
    assert other.programmed == [] and other.mode.value == "armed"


def test_esc_mode_aborts_to_minimum_on_disarm(target, host):
    spec = target.spec
    host.handshake()
    host.keepalive = heartbeat
    assert isinstance(host.request(teach(high_ms=3000)), Ack)
    status(host, EscCalPhase.HIGH, WAIT * 2.0)
    host.poll(0.3)
    assert isinstance(host.request(Disarm()), Ack)
    aborted = status(host, EscCalPhase.ABORTED, WAIT * 1.0)
    assert aborted.abort == EscCalAbort.DISARM and aborted.pulse_us == spec.rotor_safe_us
    assert aborted.supply_on == 1
    host.poll(0.2)
    tel = host.wait_type(Telemetry, WAIT * 1.0)
    assert tel.mode == ControlMode.SETPOINT and tel.pulses_us[CHANNEL] == spec.rotor_safe_us
    frames = channel_frames(target)
    last_high = max(i for i, (_, w) in enumerate(frames) if w == HIGH)
    assert all(w == spec.rotor_safe_us for _, w in frames[last_high + 1 :])  # straight to minimum
    esc = target.esc(UNIT)
    assert esc.programmed == [] and (esc.low_us, esc.high_us) == (1100.0, 1900.0)
    assert esc.mode.value == "armed"  # it saw the minimum and armed on its factory endpoints


@pytest.mark.link_watchdog
def test_esc_mode_aborts_to_minimum_on_link_loss(target, host):
    spec = target.spec

    def teach_until_high() -> int:
        since = len(host.received)
        host.keepalive = None
        host.handshake()
        host.keepalive = heartbeat
        assert isinstance(host.request(teach(high_ms=3000)), Ack)
        status(host, EscCalPhase.HIGH, WAIT * 2.0, since)
        return since

    for _ in range(10):
        # A real-time board whose host was left unscheduled for the link timeout before HIGH aborted early
        # (rightly): that attempt is made again.
        since = retry_if_starved(host, teach_until_high, within=spec.link_timeout_s, board=True)
        host.keepalive = None  # the host goes quiet
        aborted = status(host, EscCalPhase.ABORTED, WAIT * 2.0, since)
        assert aborted.abort == EscCalAbort.LINK_LOST
        tel = host.first_after(aborted, Telemetry, WAIT * 1.0)
        # Made again too: a frame arriving after the abort (the machine held the host's last frames up on
        # their way to a real-time board, past the timeout) — the board's report no longer dates the last
        # frame before the silence.
        if tel.link_age_ms >= spec.link_timeout_s * 1000 - 1:
            break
    else:
        raise AssertionError(f"no clean silence in 10 attempts; the last report: {tel}")
    assert tel.watchdog == 1 and tel.state == BoardState.DISARMED and tel.mode == ControlMode.SETPOINT
    origin = uptime_origin(target.resets(), target.now())
    t_last = origin + (tel.time_ms - tel.link_age_ms) / 1000  # the last frame the board took
    frames = channel_frames(target, since=t_last - 0.1)
    t_safe = next(t for t, w in frames if t >= t_last and w == spec.rotor_safe_us)
    assert all(w == HIGH for t, w in frames if t_last <= t < t_safe)
    frame = 1.0 / spec.frame_rate_hz
    # Not the tick interrupt (as for an armed board) but the main loop stops an ESC being taught, on its
    # next pass: under simavr 255.4-265.4 ms in 40 runs unloaded, 266.4 ms once under load (the next
    # frame start after a pass 5.4-6.4 ms past the timeout).
    assert spec.link_timeout_s - MS <= t_safe - t_last <= spec.link_timeout_s + frame + MAIN_LOOP_S
    assert target.esc(UNIT).programmed == []


def test_esc_mode_is_stopped_by_a_watchdog_reset_with_the_esc_left_at_minimum(target, host):
    spec = target.spec
    host.handshake()
    host.keepalive = heartbeat
    assert isinstance(host.request(teach(high_ms=3000)), Ack)
    status(host, EscCalPhase.HIGH, WAIT * 2.0)
    target.inject_hang()
    host.wait_type(Heartbeat, spec.mcu_watchdog_s + 2.0, lambda m: m.state == BoardState.BOOT)
    reset = target.resets()[-1]
    assert reset.cause == ResetCause.WATCHDOG
    host.poll(0.2)
    after = [(t, w) for t, w in channel_frames(target) if t > reset.t]
    assert after and all(w == spec.rotor_safe_us for _, w in after)
    host.keepalive = None
    host.reopen()
    reply = host.handshake()
    assert reply.reset_cause == ResetCause.WATCHDOG
    host.keepalive = heartbeat
    assert host.wait_type(Telemetry, WAIT * 1.0).mode == ControlMode.SETPOINT
    esc = target.esc(UNIT)
    assert esc.programmed == [] and esc.mode.value == "armed"
