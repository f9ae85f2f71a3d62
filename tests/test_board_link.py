"""The board's link layer: handshake, reliable commands (ACK/NACK, duplicates), bad bytes, link faults,
and calibration transfers, all through the sans-IO board in lockstep."""

from __future__ import annotations

import pytest
from conformance.host import heartbeat, lockstep

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.board.link import SAID_ONCE_ROOM, BoardLink
from hil.timing.clock import LockstepClock
from protocol.calibration import Reassembler, default_unit_calibration, fragment
from protocol.frame import encode_frame
from protocol.messages import (
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    CalibrationData,
    CalibrationRequest,
    ControlMode,
    Disarm,
    FaultFlag,
    Flags,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    Nack,
    NackReason,
    SetMode,
    Telemetry,
    UnitSetpoint,
)

CFG = BoardConfig(n_units=2, frame_rate_hz=100.0, telemetry_rate_hz=20.0)


def session(cfg=CFG, **kw):
    board, clock, host = lockstep(cfg, **kw)
    reply = host.handshake()
    assert reply.state == BoardState.DISARMED
    return board, clock, host


def test_hello_reply_identifies_the_board():
    board, clock, host = lockstep(CFG)
    reply = host.handshake()
    ident = CFG.identity
    assert (reply.protocol_version, reply.schema_hash, reply.n_units, reply.frame_rate_hz) == (
        1,
        SCHEMA_HASH,
        2,
        100,
    )
    assert (reply.manufacturer, reply.model, reply.serial, reply.firmware_build) == (
        ident.manufacturer,
        ident.model,
        ident.serial,
        ident.firmware_build,
    )
    assert reply.reset_cause.name == "POWER_ON"


def test_incompatible_hello_is_answered_but_opens_no_session():
    board, clock, host = lockstep(CFG)
    reply = host.handshake(schema_hash=SCHEMA_HASH ^ 1)
    assert reply.schema_hash == SCHEMA_HASH and reply.state == BoardState.BOOT
    assert board.state is BoardState.BOOT
    assert any(isinstance(m, Log) and "incompatible host" in m.text for m in host.received)
    answer = host.request(Arm())
    assert isinstance(answer, Nack) and answer.reason == NackReason.BAD_STATE


def test_retransmitted_command_is_re_acked_without_re_executing():
    board, clock, host = session()
    seq = host.send(Arm())
    host.poll(0.01)
    assert board.state is BoardState.ARMED
    assert isinstance(host.request(Disarm()), Ack)
    assert board.state is BoardState.DISARMED
    n = len(host.received)
    host.send(Arm(), seq=seq)  # the host never saw our ACK and retries (RETRANSMIT flag)
    host.poll(0.01)
    acks = [m for m in host.received[n:] if isinstance(m, Ack)]
    assert acks == [Ack(msg_id=Arm.MSG_ID, seq=seq)]
    assert board.state is BoardState.DISARMED  # answered from the cache, not executed again
    assert board.link.stats.duplicates == 1


def test_a_reused_sequence_number_without_retransmit_flag_is_a_new_command():
    board, clock, host = session()
    seq = host.send(Arm())
    host.request(Disarm())
    host.send_raw(encode_frame(Arm(), seq, Flags.ACK_REQUESTED))  # seq wrapped around: a fresh command
    host.poll(0.01)
    assert board.state is BoardState.ARMED
    assert board.link.stats.duplicates == 0


@pytest.mark.parametrize(
    ("setup", "command", "reason"),
    [
        ("boot", Arm(), NackReason.BAD_STATE),
        ("boot", Disarm(), NackReason.BAD_STATE),
        ("armed", SetMode(mode=ControlMode.RAW_PULSES), NackReason.BAD_STATE),
        ("disarmed", SetMode(mode=ControlMode.ESC_CALIBRATION), NackReason.UNSUPPORTED),
        ("armed", fragment(0, 1, b"x" * 10)[0], NackReason.BAD_STATE),
        ("disarmed", CalibrationRequest(unit=5, transfer_id=1), NackReason.OUT_OF_RANGE),
        ("disarmed", CalibrationData(unit=3, transfer_id=1, count=1), NackReason.OUT_OF_RANGE),
        ("boot", CalibrationRequest(unit=0, transfer_id=1), NackReason.BAD_STATE),
    ],
)
def test_refused_commands_are_nacked_with_their_reason(setup, command, reason):
    board, clock, host = lockstep(CFG)
    if setup != "boot":
        host.handshake()
    if setup == "armed":
        host.request(Arm())
    state = board.state
    answer = host.request(command)
    assert isinstance(answer, Nack) and answer.reason == reason
    assert board.state is state


def test_garbage_and_corrupt_frames_are_counted_and_cost_nothing_else():
    board, clock, host = session()
    host.send_raw(b"\x13\x37" * 300 + b"\x00")  # noise without a delimiter for a while
    frame = bytearray(encode_frame(heartbeat(), 9))
    frame[3] ^= 0x40  # damaged in transit
    host.send_raw(bytes(frame))
    assert isinstance(host.request(Arm()), Ack)
    tel = host.wait_type(Telemetry, 0.1)
    assert tel.rx_bad >= 2 and tel.state == BoardState.ARMED


def test_link_noise_is_seeded_and_reproducible():
    def run(seed):
        clock = LockstepClock()
        board = Board(CFG.replace(seed=seed), clock)
        board.faults.link(corrupt=0.05, drop=0.02, direction="tx")
        clock.advance(1.0)
        board.step()
        return board.take_output(), board.faults.stats

    a, sa = run(7)
    b, sb = run(7)
    c, _ = run(8)
    assert a == b and sa == sb and sa.corrupted > 0 and sa.dropped > 0
    assert a != c


def test_a_stall_starves_the_link_watchdog_then_traffic_resumes():
    board, clock, host = session()
    host.request(Arm())
    host.keepalive = lambda: ActuatorSetpoint(units=(UnitSetpoint(0.0, 200.0), UnitSetpoint(0.0, 200.0)))
    host.poll(0.2)
    board.faults.stall(0.5)
    n = len(host.received)
    host.poll(0.45)
    assert host.received[n:] == []  # nothing gets through either way
    assert board.state is BoardState.FAILSAFE
    host.poll(0.2)
    assert any(isinstance(m, Telemetry) for m in host.received[n:])
    assert board.faults.stats.stalled > 0
    assert board.state is BoardState.FAILSAFE  # traffic alone does not re-arm


# ------------------------------------------------------------------------- calibration transfers
def download(host, unit, transfer_id=5, ack=True):
    assert isinstance(host.request(CalibrationRequest(unit=unit, transfer_id=transfer_id)), Ack)
    r = Reassembler()
    # Fragments are reliable: the host acknowledges each one.
    frames_seen = []
    end = host.now() + 1.0
    while host.now() < end:
        for ev in host.deframer.feed(host._read(0.01)):
            msg = ev.message
            host.received.append(msg)
            if isinstance(msg, CalibrationData):
                frames_seen.append(ev)
                if ack:
                    host.send(Ack(msg_id=CalibrationData.MSG_ID, seq=ev.seq))
                done = r.feed(msg)
                if done is not None:
                    return done, frames_seen
    return None, frames_seen


def test_calibration_download_round_trips():
    board, clock, host = session()
    (unit, data), frames = download(host, 1)
    assert unit == 1 and data == board.calibrations[1].to_bytes()
    assert type(board.calibrations[1]).from_bytes(data).to_bytes() == data
    assert all(f.flags & Flags.ACK_REQUESTED for f in frames)


def test_unacknowledged_download_is_retried_then_abandoned():
    board, clock, host = session()
    (unit, data), frames = download(host, 0, ack=False)
    assert data == board.calibrations[0].to_bytes()
    host.poll(1.0)
    retries = [m for m in host.received if isinstance(m, CalibrationData)]
    n_frag = len(fragment(0, 5, data))
    assert len(retries) == 5 * n_frag  # first try + 4 retries, each fragment
    # said once, as the firmware says it (the emulator once said it for each fragment still pending)
    assert sum(isinstance(m, Log) and "abandoned" in m.text for m in host.received) == 1
    assert n_frag > 1
    assert isinstance(host.request(CalibrationRequest(unit=0, transfer_id=6)), Ack)  # not busy any more


def test_calibration_upload_is_stored_and_a_damaged_one_refused():
    board, clock, host = session()
    cal = default_unit_calibration()
    data = cal.to_bytes()
    parts = fragment(0, 9, data)
    for p in parts:
        assert isinstance(host.request(p), Ack)
    assert board.calibrations[0].to_bytes() == data
    assert any(isinstance(m, Log) and "calibration for unit 0 stored" in m.text for m in host.received)
    before = board.calibrations[1]
    bad = fragment(1, 10, data)
    last = bad[-1]
    bad[-1] = CalibrationData(
        unit=1,
        transfer_id=10,
        index=last.index,
        count=last.count,
        total_len=last.total_len,
        set_crc=last.set_crc ^ 0xFFFF,
        chunk=last.chunk,
    )
    answers = [host.request(p) for p in bad]
    assert isinstance(answers[-1], Nack) and answers[-1].reason == NackReason.BAD_CALIBRATION
    assert board.calibrations[1] is before


def test_missing_calibration_is_flagged_and_blocks_arming_until_uploaded():
    board, clock, host = session(calibrations=[None, default_unit_calibration()])
    tel = host.wait_type(Telemetry, 0.2)
    assert tel.faults & FaultFlag.CALIBRATION_MISSING
    answer = host.request(Arm())
    assert isinstance(answer, Nack) and answer.reason == NackReason.BAD_CALIBRATION
    for p in fragment(0, 1, default_unit_calibration().to_bytes()):
        assert isinstance(host.request(p), Ack)
    assert isinstance(host.request(Arm()), Ack)
    tel = host.wait_type(Telemetry, 0.2)
    assert not tel.faults & FaultFlag.CALIBRATION_MISSING


def test_hello_during_a_session_disarms_and_keeps_the_reset_cause():
    board, clock, host = session()
    host.request(Arm())
    reply = host.handshake()
    assert reply.state == BoardState.DISARMED and reply.reset_cause.name == "POWER_ON"
    assert isinstance(reply, HelloReply) and board.state is BoardState.DISARMED


@pytest.mark.parametrize("capacity", [512, 1024, 4096])
def test_what_is_sent_again_leaves_room_in_a_full_transmit_buffer_for_answers(capacity):
    """The firmware's rule (firmware/src/report.c): telemetry, heartbeats and download fragments stop
    short of the transmit buffer's last SAID_ONCE_ROOM bytes, so a HelloReply and Acks still fit when
    nothing drains it."""
    link = BoardLink(rx_capacity=4096, tx_capacity=capacity)
    beat = Heartbeat(time_ms=0, state=0)
    while link.send(beat) is not None:
        pass
    assert link.stats.tx_dropped == 1
    assert (
        capacity - SAID_ONCE_ROOM - len(encode_frame(beat, 0)) < link.tx_pending <= capacity - SAID_ONCE_ROOM
    )
    _, _, host = lockstep(CFG)
    assert link.send(host.handshake()) is not None  # the emulator's own HelloReply
    for _ in range(4):
        assert link.send(Ack(msg_id=Hello.MSG_ID, seq=0)) is not None
    assert link.stats.tx_dropped == 1
