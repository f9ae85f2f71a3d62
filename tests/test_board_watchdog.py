"""Link watchdog and MCU watchdog of the sans-IO board, timed exactly in lockstep (board) time."""

from __future__ import annotations

import pytest
from conformance.host import heartbeat, lockstep

from firmware_sim.board import McuPhase
from firmware_sim.board.config import BoardConfig
from protocol.messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    FaultFlag,
    Heartbeat,
    HelloReply,
    Log,
    ResetCause,
    Telemetry,
    UnitSetpoint,
    WatchdogState,
)
from protocol.pulse_widths import FINE_PER_US

CFG = BoardConfig(
    n_units=2,
    frame_rate_hz=50.0,
    telemetry_rate_hz=50.0,
    link_timeout_s=0.25,
    mcu_watchdog_s=0.5,
    boot_time_s=0.05,
)
SPIN = ActuatorSetpoint(units=(UnitSetpoint(0.3, 400.0), UnitSetpoint(-0.3, 400.0)))


def armed(cfg=CFG):
    board, clock, host = lockstep(cfg)
    host.handshake()
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: SPIN
    host.poll(0.3)
    assert board.state is BoardState.ARMED
    return board, clock, host


@pytest.mark.parametrize("frame_rate", [50.0, 333.0, 490.0])
@pytest.mark.parametrize("offset", [0.0, 0.0004, 0.0137])
def test_link_loss_failsafe_within_timeout_plus_one_frame(frame_rate, offset):
    cfg = CFG.replace(frame_rate_hz=frame_rate)
    board, clock, host = armed(cfg)
    clock.advance(offset)  # the last frame lands anywhere relative to the pulse frames
    host.send(SPIN)
    host.keepalive = None
    host.poll(0.002)  # handled on the next main-loop tick
    t_last = board.last_rx
    assert clock.now() - 0.003 < t_last <= clock.now()
    moving = board.targets[1]  # the fine width the rotor is driven at, dithered in whole 0.5 µs ticks
    assert moving / FINE_PER_US > cfg.rotor_safe_us
    ticks = {(moving >> 8) / 2, (moving >> 8) / 2 + 0.5}
    host.poll(cfg.link_timeout_s + 0.1)
    assert board.state is BoardState.FAILSAFE
    edges = board.timeline.edges(channel=1, since=t_last)
    first_safe = next(e for e in edges if e.width_us == cfg.rotor_safe_us)
    # Not before the timeout, and within the timeout plus one pulse frame (board time, exact).
    assert all(e.width_us in ticks for e in edges if e.t < first_safe.t)
    assert cfg.link_timeout_s <= first_safe.t - t_last <= cfg.link_timeout_s + 1.0 / frame_rate + 1e-9
    # The board said so: a state heartbeat stamped at the timeout, a Log, and the telemetry flags.
    hb = [m for m in host.received if isinstance(m, Heartbeat) and m.state == BoardState.FAILSAFE][0]
    t_reset = board.resets[-1].t
    assert hb.time_ms == int(round((t_last + cfg.link_timeout_s - t_reset) * 1000))
    assert any(isinstance(m, Log) and "link lost" in m.text for m in host.received)
    tel = [m for m in host.received if isinstance(m, Telemetry) and m.state == BoardState.FAILSAFE][0]
    assert tel.watchdog == WatchdogState.LINK_LOST and tel.faults & FaultFlag.LINK_LOST
    assert tel.time_ms - tel.link_age_ms == pytest.approx((t_last - t_reset) * 1000, abs=1)


def test_heartbeats_alone_keep_the_link_and_failsafe_gimbals_hold():
    board, clock, host = armed()
    host.keepalive = heartbeat
    host.poll(1.0)
    assert board.state is BoardState.ARMED  # heartbeats every 50 ms feed the 250 ms watchdog
    host.keepalive = None
    host.poll(0.4)
    assert board.state is BoardState.FAILSAFE
    cal = board.calibrations[0]
    hold = cal.gimbal_pulse_us(0.0, board.command.gimbal_mode).value  # RATE mode: zero rate (1500 µs)
    assert board.outputs[0] == hold and board.outputs[2] == hold
    assert board.outputs[1] == board.outputs[3] == CFG.rotor_safe_us


def test_failsafe_is_left_by_arm_or_hello_never_by_a_setpoint():
    board, clock, host = armed()
    host.keepalive = None
    host.poll(0.3)
    assert board.state is BoardState.FAILSAFE
    host.keepalive = lambda: SPIN
    host.poll(0.5)  # the link is back (setpoints flow) ...
    assert board.watchdog_state is WatchdogState.OK
    texts = [m.text for m in host.received if isinstance(m, Log)]
    assert "state ARMED -> FAILSAFE" in texts and "link restored" in texts  # each change is logged
    assert board.state is BoardState.FAILSAFE  # ... but the setpoints do not re-arm
    assert board.outputs[1] == CFG.rotor_safe_us
    assert isinstance(host.request(Arm()), Ack)
    host.poll(0.1)
    assert board.state is BoardState.ARMED and board.outputs[1] > CFG.rotor_safe_us
    host.keepalive = None
    host.poll(0.3)
    assert board.state is BoardState.FAILSAFE
    assert host.handshake().state == BoardState.DISARMED
    assert board.state is BoardState.DISARMED


def test_link_loss_while_disarmed_is_flagged_not_a_state_change():
    board, clock, host = lockstep(CFG)
    host.handshake()
    host.poll(0.4)
    assert board.state is BoardState.DISARMED
    assert board.watchdog_state is WatchdogState.LINK_LOST
    host.send(heartbeat())
    host.poll(0.01)
    assert board.watchdog_state is WatchdogState.OK


def test_no_link_watchdog_before_the_handshake():
    board, clock, host = lockstep(CFG)
    host.poll(2.0)
    assert board.state is BoardState.BOOT and board.watchdog_state is WatchdogState.OK
    beats = [m for m in host.received if isinstance(m, Heartbeat)]
    assert len(beats) >= 9 and all(b.state == BoardState.BOOT for b in beats)
    assert not any(isinstance(m, Telemetry) for m in host.received)  # telemetry needs a session


def test_hang_resets_after_the_mcu_watchdog_and_reports_it():
    board, clock, host = armed()
    t_hang = clock.now() + 0.0123
    board.faults.hang(at=t_hang)
    host.poll(0.05)
    assert board.phase is McuPhase.HUNG
    frozen = board.targets  # the main loop's last fine widths
    t_last = board.last_rx  # the last frame the main loop handled
    before = len(host.received)
    host.poll(t_hang + CFG.mcu_watchdog_s - 0.005 - clock.now())
    # Hung: the main loop says nothing (no telemetry, no ACK, no heartbeat) while the host keeps sending
    # and the pulse timers keep their widths: the frame interrupt dithers the last targets on — but the
    # tick interrupt puts the rotors at the safe pulse once the link has been silent for its timeout
    # (the host's frames lie unread: firmware/src/app.c, app_tick), long before the MCU watchdog's reset.
    assert board.phase is McuPhase.HUNG and host.received[before:] == []
    gimbals, rotors = range(0, len(frozen), 2), range(1, len(frozen), 2)
    assert [board.targets[ch] for ch in gimbals] == [frozen[ch] for ch in gimbals]
    assert [board.targets[ch] for ch in rotors] == [int(CFG.rotor_safe_us * FINE_PER_US)] * len(rotors)
    host.poll(0.1)
    assert board.resets[-1].cause is ResetCause.WATCHDOG
    t_reset = board.resets[-1].t
    assert t_reset == pytest.approx(t_hang + CFG.mcu_watchdog_s, abs=1e-6)
    during = [f for f in board.timeline.frames if t_hang < f.t < t_reset]
    # the rotors' stop: the link's timeout after the last frame the main loop handled, plus the 4 ms the
    # tick interrupt stands back while received bytes wait, plus at most one frame
    t_stop = t_last + CFG.link_timeout_s + 0.004
    held = [f for f in during if f.t >= t_stop + 1.0 / CFG.frame_rate_hz]
    assert held and all(f.widths[ch] == CFG.rotor_safe_us for f in held for ch in rotors)
    running = [f for f in during if f.t < t_stop]
    for ch in [*gimbals, *(rotors if running else ())]:  # dithered on, as the main loop left them
        kept = during if ch in gimbals else running
        q = frozen[ch]
        assert all(f.widths[ch] in ((q >> 8) / 2, (q >> 8) / 2 + 0.5) for f in kept)
        mean = sum(f.widths[ch] for f in kept) / len(kept)  # the fine width, to the dither's one tick
        assert mean == pytest.approx(q / FINE_PER_US, abs=0.5 / len(kept))
    after = [f for f in board.timeline.frames if f.t >= t_reset]
    # outputs off during the boot, then safe outputs in BOOT
    assert after[0].t == pytest.approx(t_reset + CFG.boot_time_s, abs=1e-6)
    assert after[0].widths[1] == CFG.rotor_safe_us
    assert board.state is BoardState.BOOT
    host.keepalive = None
    reply = host.handshake()
    assert reply.reset_cause == ResetCause.WATCHDOG
    assert "boot: reset cause WATCHDOG" in [m.text for m in host.received if isinstance(m, Log)]
    tel = host.wait_type(Telemetry, 0.2)
    assert tel.faults & FaultFlag.MCU_WATCHDOG_RESET
    assert tel.time_ms < 300  # uptime restarted at the reset


def test_bytes_sent_to_a_hung_board_are_lost_and_overflow_is_counted():
    cfg = CFG.replace(rx_buffer_bytes=256)
    board, clock, host = armed(cfg)
    host.keepalive = None
    board.faults.hang()
    for _ in range(40):
        host.send(SPIN)
    host.poll(0.1)
    assert board.link.stats.rx_overflow > 0
    host.poll(0.6)
    assert board.phase is McuPhase.RUNNING and board.state is BoardState.BOOT
    # a host frame sent during the boot is lost: the UART is off in reset
    assert isinstance(host.handshake(), HelloReply)


def test_a_hang_due_during_boot_takes_the_main_loop_once_it_runs():
    from conformance.host import LockstepHost

    from firmware_sim.board import Board
    from hil.timing.clock import LockstepClock

    clock = LockstepClock()
    board = Board(CFG, clock)
    host = LockstepHost(board, clock)
    board.faults.hang(at=0.02)  # the board is still booting (50 ms)
    host.poll(0.04)
    assert board.phase is McuPhase.RESET and board.faults.hangs == [0.02]  # pending, not lost
    host.poll(0.02)
    assert board.phase is McuPhase.HUNG and not board.faults.hangs
    host.poll(CFG.mcu_watchdog_s)
    assert [r.cause for r in board.resets] == [ResetCause.POWER_ON, ResetCause.WATCHDOG]
    assert board.resets[-1].t == pytest.approx(CFG.boot_time_s + CFG.mcu_watchdog_s, abs=2e-3)


def test_a_dead_esc_on_a_channel_the_board_lacks_is_refused_by_the_api():
    from protocol.errors import ConfigError

    board, clock, host = lockstep(CFG)
    with pytest.raises(ConfigError, match="channel 4 does not exist") as info:
        board.faults.dead_esc(2 * CFG.n_units)
    assert info.value.where == "faults.dead_esc.channel"
    board.faults.dead_esc(2 * CFG.n_units - 1)  # the last rotor channel is fine
