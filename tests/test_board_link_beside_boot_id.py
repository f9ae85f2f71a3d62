"""A board that restarted, told by its boot id (``HelloReply.boot_id``, ``Heartbeat.boot_id``).

Before the boot id the host knew a reset only by circumstance: the uptime or the frame count going back,
BOOT mid-session, an uptime shorter than the board must have run. A board restarted within
``AGE_SLACK_S`` (0.5 s) of when it was last heard of, that then ran longer than the old one had, passed
for the board that was there (docs/runtime-link.md); so did another board on a reused port whose counts
were ahead of the old one's. Both are reset reports now, with the boot id as evidence.

The host's sans-IO session against the emulated board (``firmware_sim.board.Board``) in lockstep, the
board restarted at drawn moments of a session (before its first sample, mid-stream, armed), each within
0.5 s of when it was last heard of; then through real ptys, a ``firmware-sim`` killed with SIGKILL and
its link pointed at another one that ran longer and took more frames than it had.
"""

from __future__ import annotations

import logging
import random
import signal
import time
from pathlib import Path

import pytest
from test_board_client_pty import drive, firmware_sim

from firmware_sim.board.config import BoardConfig
from firmware_sim.board.core import Board
from hil.link.board import BoardClient, BoardResetEvent, ClientConfig, ConnectedEvent, LogEvent, StateEvent
from hil.link.board.session import AGE_SLACK_S, DROP_WARN_EVERY_S, STALE_REANCHOR, Phase, Session
from hil.timing.clock import LockstepClock
from protocol.errors import BoardReset
from protocol.frame import Deframer, Frame, encode_frame
from protocol.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    ResetCause,
    Severity,
    Telemetry,
    UnitSetpoint,
    UnitState,
)
from protocol.reliable import CommandState

SEED = 20261205
STEP_S = 0.002
UNITS = 2


def setpoint(speed: float = 300.0) -> ActuatorSetpoint:
    return ActuatorSetpoint(units=tuple(UnitSetpoint(0.1, speed) for _ in range(UNITS)))


class Bench:
    """One host session and the board on its link, on one lockstep clock; the board can be replaced."""

    def __init__(self, boot_seed: int) -> None:
        self.clock = LockstepClock()
        self.config = BoardConfig(n_units=UNITS, telemetry_rate_hz=50.0)
        self.board: Board | None = Board(self.config, self.clock, boot_ids=random.Random(boot_seed))
        self.session = Session()
        self.events: list[object] = []

    def now(self) -> float:
        return self.clock.now()

    def to_board(self, data: bytes) -> None:
        if data and self.board is not None:
            self.board.feed(data)

    def run(self, seconds: float, sp: ActuatorSetpoint | None = None) -> None:
        """``seconds`` of lockstep time: the board's bytes to the session, the session's to the board."""
        end = self.now() + seconds
        while self.now() < end - 1e-9:
            self.clock.advance(STEP_S)
            now = self.now()
            if self.board is not None:
                self.board.step()
                data = self.board.take_output()
                if data:
                    self.to_board(self.session.feed(data, now))
            if sp is not None and self.session.phase is Phase.READY and self.session.pending_reset is None:
                self.to_board(self.session.setpoint(sp, now))
            self.to_board(self.session.poll(now))
            self.events += self.session.take_events()

    def connect(self) -> None:
        """A handshake, up to its answer (no sample of the board taken after it yet)."""
        self.to_board(self.session.link_up(self.now()))
        for _ in range(round(1.0 / STEP_S)):
            self.run(STEP_S)
            if self.session.phase is Phase.READY:
                return
        raise AssertionError(f"no session: {self.session.phase}, {self.session.failure}")

    def resets(self) -> list[BoardResetEvent]:
        return [e for e in self.events if isinstance(e, BoardResetEvent)]


@pytest.mark.parametrize("moment", ["before the first sample", "mid-stream", "armed"])
def test_a_board_restarted_within_the_age_slack_is_reported_by_its_boot_id(moment: str):
    """Killed at a drawn moment, a new board (another process: other boot ids) up within 0.5 s of when
    the old one was last heard of, and found again by the host once it has run longer than the old one
    had: reported reset, once, its boot id the evidence, with the cause of its answer; an armed host's
    setpoints refused until it arms again."""
    rng = random.Random(f"{SEED} {moment}")
    for draw in range(3):
        bench = Bench(boot_seed=rng.randrange(1 << 30))
        bench.run(0.1)  # the board boots (BOOT heartbeats, nothing taken: no session yet)
        bench.connect()
        if moment == "mid-stream":
            bench.run(rng.uniform(0.05, 2.0))
        elif moment == "armed":
            cmd, data = bench.session.command(Arm(), bench.now())
            bench.to_board(data)
            bench.run(0.05)
            assert cmd.state is CommandState.ACKED and bench.session.armed
            bench.run(rng.uniform(0.05, 2.0), setpoint())
        old = bench.board
        assert old is not None and bench.session.boot_id == old.boot_id != 0
        heard = bench.session.last_heard
        assert heard is not None
        uptime_then = old.uptime_ms() / 1000.0
        # the port vanishes with the board; a new one is up within the age slack of when it was last heard
        bench.session.link_down(bench.now(), "the port vanished")
        bench.board = None
        bench.clock.advance(max(0.0, rng.uniform(0.0, AGE_SLACK_S - 0.06) - (bench.now() - heard)))
        new = Board(bench.config, bench.clock, boot_ids=random.Random(rng.randrange(1 << 30) + (1 << 31)))
        bench.board = new
        bench.run(uptime_then + rng.uniform(0.2, 1.5))  # it has run longer than the old one had
        assert new.uptime_ms() / 1000.0 > uptime_then
        bench.connect()
        bench.run(0.5, setpoint() if moment == "armed" else None)
        where = f"{moment}, draw {draw}"
        [reset] = bench.resets()
        evidence = f"its boot id changed from {old.boot_id:#010x} to {new.boot_id:#010x}"
        assert reset.evidence.startswith(evidence), (where, reset.evidence)
        assert reset.cause is ResetCause.POWER_ON and reset.during_session, where
        assert [e.reconnects for e in bench.events if isinstance(e, ConnectedEvent)] == [0, 1], where
        assert bench.session.counters.resets == 1 and bench.session.boot_id == new.boot_id, where
        assert bench.session.state is BoardState.DISARMED, where  # never re-armed on its own
        if moment == "armed":
            with pytest.raises(BoardReset, match="POWER_ON"):
                bench.session.setpoint(setpoint(), bench.now())
            assert new.state is BoardState.DISARMED  # nothing of the old session reached the new board
        else:
            assert bench.session.pending_reset is None, where


def test_a_reset_told_by_a_heartbeat_alone_is_reported_once():
    """A board that reset with the link up (a reset the host saw nothing else of): its next heartbeat's
    boot id tells it; the session handshakes again for the cause and reports it once."""
    bench = Bench(boot_seed=3)
    bench.connect()
    bench.run(0.5)
    board = bench.board
    assert board is not None
    before = board.boot_id
    board.reset(ResetCause.EXTERNAL)
    bench.run(0.5)
    [reset] = bench.resets()
    assert reset.cause is ResetCause.EXTERNAL and reset.during_session
    assert reset.evidence.startswith(f"its boot id changed from {before:#010x} to {board.boot_id:#010x}")
    assert bench.session.boot_id == board.boot_id and bench.session.phase is Phase.READY
    info = bench.session.info  # the new handshake's answer: the new boot, said where a run records it
    assert info is not None and info.boot_id == board.boot_id != before
    assert f"boot {board.boot_id:#010x}" in info.describe()


class BoardWithoutBootId(Board):
    """An older board: boot id 0 ("the board does not say") in every HelloReply and Heartbeat."""

    def _next_boot_id(self, last: int) -> int:
        return 0


def test_a_board_that_sends_no_boot_id_is_judged_by_its_counts_as_before():
    """A reset of a board that sends boot id 0 is still told by its uptime and state."""
    bench = Bench(boot_seed=4)
    board = BoardWithoutBootId(bench.config, bench.clock)
    bench.board = board
    bench.connect()
    bench.run(0.5)
    assert bench.session.boot_id is None
    assert bench.session.info is not None and "boot" not in bench.session.info.describe()
    board.reset(ResetCause.EXTERNAL)
    bench.run(0.5)
    [reset] = bench.resets()
    assert "boot id" not in reset.evidence
    assert "uptime went back" in reset.evidence or "BOOT" in reset.evidence, reset.evidence


# ====================================================================== real ptys
def test_another_board_on_the_killed_boards_link_is_reported_by_its_boot_id(tmp_path: Path):
    """A firmware-sim killed with SIGKILL leaves its link behind; the name can reach another board (a pty
    number reused, a link repointed) with the same identity, which has run longer and taken more frames
    than the host's board had, not in BOOT: nothing in its counts or state tells it from the board the
    host had (before the boot id, it was taken for it). Its boot id does: a reset, reported once; the
    armed host's setpoints refused until it arms again."""
    link, other = tmp_path / "board", tmp_path / "board-2"
    config = ClientConfig(reconnect_first_s=0.02, reconnect_max_s=0.2)
    with firmware_sim("--units", "2", "--link", str(other)):
        # the other board runs on, and takes frames: more than the host's board will have
        with BoardClient(str(other)) as elsewhere:
            elsewhere.start()
            busy = lambda: elsewhere.telemetry is not None and elsewhere.telemetry.rx_frames >= 150  # noqa: E731
            drive(elsewhere, None, busy, 10.0)
        with firmware_sim("--units", "2", "--link", str(link)) as first:
            client = BoardClient(str(link), config=config)
            try:
                client.connect()
                client.start()
                client.arm()
                taken = lambda: client.telemetry is not None and client.telemetry.rx_frames >= 20  # noqa: E731
                drive(client, setpoint(), taken, 3.0)
                first.send_signal(signal.SIGKILL)
                link.unlink()
                events = drive(client, None, lambda: not client.connected, 2.0)
                link.symlink_to(other.readlink())
                drive(client, None, lambda: client.connected, 5.0, events)
                time.sleep(0.3)  # its samples come in
                events += client.service()
                [reset] = [e for e in events if isinstance(e, BoardResetEvent)]
                assert "boot id changed" in reset.evidence and reset.during_session, reset
                assert client.state is BoardState.DISARMED
                with pytest.raises(BoardReset):
                    client.send_setpoint(setpoint())
            finally:
                client.close()


@pytest.mark.parametrize("lost_s", [0.0, 0.05, 0.12, 0.3])
@pytest.mark.parametrize("board_type", [Board, BoardWithoutBootId], ids=["boot-id", "counts"])
def test_an_armed_board_that_reset_is_one_reset_reported_before_the_state_it_left(lost_s, board_type):
    """An armed board resets with the link up, its first ``lost_s`` of output lost (its BOOT heartbeats,
    on a noisy line): the host is told one reset, and told it before any ARMED → DISARMED — which, told
    first, the run read as a Disarm no command asked for: a second fault for the one reset, and a false
    one."""
    bench = Bench(boot_seed=5)
    bench.board = board_type(bench.config, bench.clock, boot_ids=random.Random(5))
    bench.connect()
    cmd, data = bench.session.command(Arm(), bench.now())
    bench.to_board(data)
    bench.run(0.2, setpoint())
    assert cmd.state is CommandState.ACKED and bench.session.state is BoardState.ARMED
    board = bench.board
    assert board is not None
    board.reset(ResetCause.EXTERNAL)
    end = bench.now() + lost_s
    while bench.now() < end - 1e-9:  # the board runs, its bytes lost
        bench.clock.advance(STEP_S)
        board.step()
        board.take_output()
    bench.events.clear()
    bench.run(0.6)
    [reset] = bench.resets()
    disarmed = [
        i
        for i, e in enumerate(bench.events)
        if isinstance(e, StateEvent) and (e.old, e.new) == (BoardState.ARMED, BoardState.DISARMED)
    ]
    assert all(bench.events.index(reset) < i for i in disarmed), bench.events[:6]


class _Hand:
    """A board played frame by frame against a host session: its answers built by the protocol's own
    encoder, to say what no emulated board says (an uptime gone back while it still says ARMED)."""

    def __init__(self) -> None:
        self.session, self.t, self.seq = Session(), 0.0, 0
        self.events: list[object] = []

    def to_host(self, message: object, seq: int | None = None) -> list[Frame]:
        """``message`` to the session; what the session sent back, decoded."""
        self.t += 0.01
        if seq is None:
            self.seq = (self.seq + 1) % 256
        out = self.session.feed(encode_frame(message, self.seq if seq is None else seq), self.t)
        out += self.session.poll(self.t)
        self.events += self.session.take_events()
        return [f for f in Deframer().feed(out) if isinstance(f, Frame)]

    def reply(self, frames: list[Frame], boot_id: int, state: BoardState) -> list[Frame]:
        """The HelloReply to the Hello among ``frames``."""
        [hello] = [f for f in frames if isinstance(f.message, Hello)]
        reply = HelloReply(
            protocol_version=PROTOCOL_VERSION, schema_hash=SCHEMA_HASH, reset_cause=ResetCause.EXTERNAL,
            state=state, n_units=UNITS, frame_rate_hz=50, boot_id=boot_id, manufacturer="m", model="m",
            description="d", version="1", uri="", serial="S1",
        )  # fmt: skip
        return self.to_host(reply, hello.seq)


def _armed(boot_id: int) -> _Hand:
    """A session handshaken with a board of ``boot_id`` (0: one that does not say its boot id), armed,
    three Heartbeats heard (uptime 5 000, 5 200, 5 400 ms), the events so far cleared."""
    hand = _handshaken_to(boot_id)
    cmd, data = hand.session.command(Arm(), hand.t)
    [arm] = [f for f in Deframer().feed(data) if isinstance(f, Frame)]
    hand.to_host(Ack(msg_id=Arm.MSG_ID, seq=arm.seq))
    assert cmd.state is CommandState.ACKED and hand.session.state is BoardState.ARMED
    for ms in (5000, 5200, 5400):
        hand.to_host(Heartbeat(time_ms=ms, state=BoardState.ARMED, boot_id=boot_id))
    hand.events.clear()
    return hand


def test_a_reset_found_by_the_uptime_is_told_before_the_disarmed_state_the_handshake_finds():
    """An armed board's uptime goes back while it still says ARMED; the handshake that asks why finds it
    DISARMED. The reset is told first: told after the state, a run read ARMED → DISARMED as a Disarm no
    command asked for (two faults for one reset, one false: a fake board's report). A board that does not
    say its boot id: one that does is believed over a count gone back (the tests below)."""
    hand = _armed(0)
    asked = hand.to_host(Heartbeat(time_ms=10, state=BoardState.ARMED, boot_id=0))  # uptime back
    hand.reply(asked, 0, BoardState.DISARMED)
    [reset] = [e for e in hand.events if isinstance(e, BoardResetEvent)]
    [disarmed] = [e for e in hand.events if isinstance(e, StateEvent) and e.new is BoardState.DISARMED]
    assert hand.events.index(reset) < hand.events.index(disarmed), hand.events


def _handshaken() -> _Hand:
    return _handshaken_to(0x1234)


def test_a_reset_storm_is_every_reset_counted_and_a_warning_a_second(caplog):
    """A board whose boot id changes at every heartbeat (2 000 of them, 10 ms apart): every reset is
    counted and an event, and the log holds a warning a second (it held 2 000, burying the host's own)."""
    hand = _handshaken()
    caplog.set_level(logging.WARNING, logger="hil.link.board.session")
    boot = 0x1234
    for k in range(2000):
        boot = boot + 1
        asked = hand.to_host(Heartbeat(time_ms=100 + k, state=BoardState.DISARMED, boot_id=boot))
        if any(isinstance(f.message, Hello) for f in asked):
            hand.reply(asked, boot, BoardState.DISARMED)
    resets = [e for e in hand.events if isinstance(e, BoardResetEvent)]
    lines = [r for r in caplog.records if "board reset" in r.getMessage()]
    assert len(resets) == hand.session.counters.resets >= 1000
    span_s = hand.t - 1.0
    assert 1 <= len(lines) <= span_s / DROP_WARN_EVERY_S + 2
    assert any("more resets since the last warning" in r.getMessage() for r in lines[1:])


@pytest.mark.parametrize(
    "text", ["\x1b[2J\x1b[H\rINFO hil: run completed\x1b[8m", "a\u202eb", "\x07\x00\x7f\x9b[31m", "ok\tline"]
)
def test_a_board_log_reaches_the_terminal_with_its_control_characters_escaped(text, caplog):
    """A board's Log goes to the operator's terminal: its escape sequences cleared the screen and hid the
    host's lines, a CR wrote over them. They are escaped in the log line; the event keeps the text."""
    hand = _handshaken()
    caplog.set_level(logging.INFO, logger="hil.link.board.session")
    hand.to_host(Log(severity=Severity.ERROR, code=1, text=text))
    [line] = [r.getMessage() for r in caplog.records if r.getMessage().startswith("board: ")]
    assert not any(ord(c) < 0x20 and c != "\t" or 0x7F <= ord(c) < 0xA0 or c == "\u202e" for c in line)
    [event] = [e for e in hand.events if isinstance(e, LogEvent)]
    assert event.log.text == text


@pytest.mark.parametrize("kind", ["Telemetry", "Heartbeat"])
@pytest.mark.parametrize("behind_ms", [1, 150, 5000])
def test_an_old_sample_of_the_same_boot_is_dropped_and_counted_not_a_reset(kind, behind_ms):
    """A sample behind what the same boot already said — a frame replayed, or held back on the way longer
    than an overtaking — from a board that says its boot id, not saying BOOT: dropped and counted, the
    board kept armed, no Hello, the held Telemetry still the newest. It was a reset: a Hello that disarmed
    the board, a reset counted that never happened and, a Telemetry, one a second old held as the board's
    word on now."""
    hand = _armed(0x1234)
    resets = hand.session.counters.resets  # the one the handshake's answer told of (EXTERNAL)
    hand.to_host(_telemetry(hand, 5500, BoardState.ARMED))

    def sample(time_ms: int) -> Telemetry | Heartbeat:
        if kind == "Telemetry":
            return _telemetry(hand, time_ms, BoardState.ARMED)
        return Heartbeat(time_ms=time_ms, state=BoardState.ARMED, boot_id=0x1234)

    hand.to_host(sample(5510))  # the newest of its own kind: the old one goes back on it
    asked = hand.to_host(sample(5510 - behind_ms))
    s = hand.session
    assert not any(isinstance(f.message, Hello) for f in asked)
    assert s.counters.resets == resets and s.counters.board_samples_stale == 1
    assert s.armed and s.state is BoardState.ARMED
    assert s.telemetry is not None and s.telemetry.time_ms == (5510 if kind == "Telemetry" else 5500)
    assert not [e for e in hand.events if isinstance(e, (BoardResetEvent, StateEvent))]
    hand.to_host(_telemetry(hand, 5520, BoardState.ARMED))  # the board goes on: taken
    assert s.telemetry.time_ms == 5520 and s.counters.board_samples_stale == 1


def test_after_one_sample_ahead_within_the_slack_the_boards_own_are_taken_again():
    """One Heartbeat 4 s ahead of the board (within the leaps' slack, so taken); the board's honest
    samples after it are behind it: the first two dropped, the third anchors the counts anew — no reset,
    the board kept armed, its samples taken from then on."""
    hand = _armed(0x1234)
    resets = hand.session.counters.resets
    hand.to_host(Heartbeat(time_ms=9400, state=BoardState.ARMED, boot_id=0x1234))
    for k in range(STALE_REANCHOR + 2):
        hand.to_host(_telemetry(hand, 5420 + 20 * k, BoardState.ARMED))
    s = hand.session
    assert s.counters.resets == resets and s.armed
    assert s.counters.board_samples_stale == STALE_REANCHOR - 1 and s.counters.board_reanchors == 1
    assert s.telemetry.time_ms == 5420 + 20 * (STALE_REANCHOR + 1)


def test_a_board_that_restarts_with_the_same_boot_id_saying_boot_is_still_a_reset():
    """A simulated board may draw the same boot id at its restart; it says BOOT until a handshake, and
    that with its uptime gone back is a reset, as before."""
    hand = _armed(0x1234)
    resets = hand.session.counters.resets
    asked = hand.to_host(Heartbeat(time_ms=30, state=BoardState.BOOT, boot_id=0x1234))
    assert any(isinstance(f.message, Hello) for f in asked)
    hand.reply(asked, 0x1234, BoardState.DISARMED)
    assert hand.session.counters.resets == resets + 1 and hand.session.counters.board_samples_stale == 0
    assert [e for e in hand.events if isinstance(e, BoardResetEvent)]


def _telemetry(hand: _Hand, time_ms: int, state: BoardState) -> Telemetry:
    """A Telemetry of the hand-played board (its units at rest, every channel at 1 500 µs)."""
    info = hand.session.info
    assert info is not None
    return Telemetry(
        time_ms=time_ms,
        state=state,
        units=tuple(UnitState() for _ in range(info.n_units)),
        pulses_us=(1500,) * info.n_channels,
    )


@pytest.mark.parametrize("boot_id", [0, 0x1234])
def test_a_telemetry_overtaken_across_the_uptimes_wrap_is_taken_not_refused_as_a_leap(boot_id):
    """A board up 49.7 days: a Telemetry made 7 ms before its uptime wraps arrives after a Heartbeat made
    2 ms after it (CAN by priority). It went back by 7 ms — overtaken, taken — not on by 49 days: it was
    refused as a leap ("its uptime leapt from 2 ms to 4294967291 ms"), the board's own frame dropped."""
    hand = _handshaken_to(boot_id)
    hand.events.clear()
    wrap = 1 << 32
    for ms in (wrap - 300, wrap - 200, wrap - 100):
        hand.to_host(_telemetry(hand, ms, BoardState.DISARMED))
        hand.to_host(Heartbeat(time_ms=ms + 1, state=BoardState.DISARMED, boot_id=boot_id))
    asked = hand.to_host(Heartbeat(time_ms=2, state=BoardState.DISARMED, boot_id=boot_id))
    asked += hand.to_host(_telemetry(hand, wrap - 5, BoardState.DISARMED))
    s = hand.session
    assert not any(isinstance(f.message, Hello) for f in asked)
    assert (s.counters.board_leaps, s.counters.board_samples_overtaken) == (0, 1)
    assert s.telemetry is not None and s.telemetry.time_ms == wrap - 5
    hand.to_host(_telemetry(hand, 25, BoardState.DISARMED))  # on past the wrap: taken, no reset
    assert s.telemetry.time_ms == 25 and s.counters.board_samples_stale == 0
    assert not [e for e in hand.events if isinstance(e, BoardResetEvent)]


def _handshaken_to(boot_id: int) -> _Hand:
    """A session handshaken with a board of ``boot_id`` (0: one that does not say it)."""
    hand = _Hand()
    hand.t = 1.0
    sent = [f for f in Deframer().feed(hand.session.link_up(hand.t)) if isinstance(f, Frame)]
    hand.reply(sent, boot_id, BoardState.DISARMED)
    return hand
