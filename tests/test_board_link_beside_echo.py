"""A port that echoes what the host writes: a loopback plug (TX joined to RX), an RS-485 or half-duplex
adapter that hears its own transmitter — alone, or passing a real board's frames as well.

Through the sans-IO session with injected time (the properties), through real ptys with the real board
client (an echoing far side served by the test; ``firmware-sim`` behind a half-duplex echoing proxy), and
through ``hil run`` and ``hil calibrate`` as processes.

Before the fixes: against an echo alone the tools ended with "the board did not answer the handshake (no
answer after 50 tries)" — not a word of the 50 Hellos that came back. Behind an echoing adapter a real
board's session was upset within 50 ms: the host's own Heartbeat came back (state 0, BOOT, and the host's
clock for uptime) and was taken as the board's — a spurious board reset, a new handshake, an armed board's
setpoints refused with BoardReset; every echo made a sequence gap; and once the board fell silent, the
echoes of the host's heartbeats kept it looking alive (``last_heard`` moving, no silence ever reported).
An upload's fragment coming back was taken for a download's and NACKed to the board.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from operator_support import Operated
from sim_support import Sim, sims

from hil.link.board import BoardClient, ClientConfig, Phase, Session, SilenceEvent
from hil.scenario.paths import SHARED_DATA
from protocol.calibration import default_unit_calibration
from protocol.calibration import fragment as fragment_of
from protocol.errors import LinkTimeout
from protocol.frame import Framer
from protocol.messages import (
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    Flags,
    Hello,
    HelloReply,
    Telemetry,
    UnitSetpoint,
    UnitState,
)

UNITS = 2
ECHO_SAID = "the port echoes what the host sends"


def hello_reply() -> HelloReply:
    return HelloReply(
        schema_hash=SCHEMA_HASH, state=BoardState.DISARMED, n_units=UNITS, frame_rate_hz=50, model="SCRIPTED"
    )


def connected() -> tuple[Session, Framer]:
    """A session after a handshake with :func:`hello_reply`'s board (its events taken), and the board's
    framer."""
    s = Session()
    s.link_up(0.0)
    board = Framer()
    s.feed(board.encode(hello_reply())[1], 0.01)
    assert s.phase is Phase.READY
    s.take_events()
    return s, board


def telemetry(time_ms: int, rx_frames: int = 0) -> Telemetry:
    return Telemetry(
        time_ms=time_ms,
        state=BoardState.DISARMED,
        units=tuple(UnitState() for _ in range(UNITS)),
        pulses_us=(1000,) * (2 * UNITS),
        rx_frames=rx_frames,
    )


def setpoint(speed: float = 100.0) -> ActuatorSetpoint:
    return ActuatorSetpoint(units=tuple(UnitSetpoint(0.0, speed) for _ in range(UNITS)))


# ====================================================================== sans-IO: the session
def echoed_session(board_uptime_ms: int = 7_000) -> tuple[Session, Framer]:
    """A session through an echoing adapter: its Hello came back, then the board answered."""
    s = Session()
    s.feed(s.link_up(0.0), 0.001)  # the Hello's echo
    board = Framer()
    s.feed(board.encode(hello_reply())[1], 0.01)
    s.feed(board.encode(telemetry(board_uptime_ms))[1], 0.02)
    assert s.phase is Phase.READY
    s.take_events()
    return s, board


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    steps=st.lists(
        st.tuples(st.floats(0.001, 0.2), st.booleans(), st.booleans(), st.integers(0, 3)),
        min_size=1,
        max_size=60,
    ),
    board_uptime_ms=st.integers(0, 2**32 - 1),
)
def test_the_hosts_echoes_among_a_boards_frames_are_counted_never_taken_as_the_boards(steps, board_uptime_ms):
    """A board streaming telemetry behind an adapter that echoes every byte the host writes (heartbeats,
    setpoints, an Arm), at drawn moments and in drawn order against the board's frames: the session stays
    up, no reset is seen, every echo is counted, the board's frames are all taken and no sequence gap is
    made up. Before the fix the host's first Heartbeat back (state BOOT, the host's clock) was a board
    reset."""
    s, board = echoed_session(board_uptime_ms)
    t, echoes, telemetries = 0.02, 1, 0
    for dt, send_setpoint, echo_first, repeats in steps:
        t += dt
        out = s.poll(t)
        if send_setpoint:
            out += s.setpoint(setpoint(), t)
        uptime = (board_uptime_ms + round((t - 0.02) * 1000)) % 2**32
        frame = board.encode(telemetry(uptime))[1]
        echo = out * repeats  # an adapter may hand back a frame more than once
        for data in (echo, frame) if echo_first else (frame, echo):
            s.feed(data, t + 0.001)
        echoes += out.count(0) * repeats
        telemetries += 1
        assert s.phase is Phase.READY
        assert s.telemetry is not None and s.telemetry.time_ms == uptime
    assert s.counters.resets == 0 and s.counters.board_leaps == 0
    assert s.seq_gaps == 0 and s.duplicates == 0
    assert s.counters.echoes == echoes and s.counters.host_frames == 0
    assert s.commands.stats.unmatched_answers == 0
    assert sum(type(e).__name__ == "TelemetryEvent" for e in s.take_events()) == telemetries


def test_an_armed_board_behind_an_echo_is_not_taken_for_reset_by_the_hosts_heartbeat():
    """The host's idle Heartbeat (state 0 = BOOT, time = the host's clock) comes back while the board is
    armed: before the fix, a board reset mid-session — a new handshake, and setpoints raising BoardReset."""
    s, board = echoed_session(9_000)
    cmd, out = s.command(Arm(), 0.03)
    s.feed(out, 0.031)
    s.feed(board.encode(Ack(msg_id=cmd.msg_id, seq=cmd.seq))[1], 0.032)
    assert s.armed
    beat = s.poll(0.2)
    assert beat and s.counters.heartbeats_sent == 1
    s.feed(beat, 0.201)
    assert s.phase is Phase.READY and s.pending_reset is None and s.counters.resets == 0
    assert s.setpoint(setpoint(), 0.21)  # sent: no BoardReset


def test_echoes_never_keep_a_silent_board_looking_alive():
    """The board stops; the adapter keeps echoing the host's heartbeats: ``last_heard`` stays at the
    board's last frame and the silence is reported after ``silence_after_s``; the board's next frame
    ends it."""
    s, board = echoed_session()
    last_board = 0.02
    t = last_board
    while t < last_board + 3.0:
        t = round(t + 0.01, 6)
        s.feed(s.poll(t), t + 0.0005)  # only echoes come
    assert s.last_heard == last_board
    silences = [e for e in s.take_events() if isinstance(e, SilenceEvent)]
    assert len(silences) == 1 and not silences[0].ended and silences[0].since == last_board
    assert silences[0].t == pytest.approx(last_board + s.config.silence_after_s, abs=0.011)
    assert s.counters.silences == 1
    s.feed(board.encode(telemetry(7_000 + round((t - last_board) * 1000)))[1], t + 0.01)
    assert [e.ended for e in s.take_events() if isinstance(e, SilenceEvent)] == [True]
    assert s.counters.echoes > 50


def test_an_uploads_fragment_coming_back_is_not_taken_for_a_downloads():
    """An upload's CalibrationData echoed: before the fix it was answered as a download's fragment (a
    Nack BAD_STATE written to the board, counted as a calibration answer); the board's Ack of it, coming
    after, still settles it."""
    s, board = echoed_session()
    fragments = s.upload_fragments(0, default_unit_calibration())
    cmd, out = s.command(fragments[0], 0.03)
    assert s.feed(out, 0.031) == b""  # nothing written back
    assert s.counters.calibration_answers == 0 and s.counters.echoes == 2
    s.feed(board.encode(Ack(msg_id=cmd.msg_id, seq=cmd.seq))[1], 0.032)
    assert cmd.ok


def test_the_hosts_answer_to_a_downloads_fragment_coming_back_is_no_stray_answer():
    """The host's Ack of a download's fragment echoed: not taken for an answer to one of its commands (it
    was counted as an unmatched one), and the download completes."""
    s, board = echoed_session()
    calibration = default_unit_calibration()
    download, out = s.start_download(0, 0.03)
    s.feed(out, 0.031)
    request = s.commands.pending[0]
    s.feed(board.encode(Ack(msg_id=request.msg_id, seq=request.seq))[1], 0.032)
    for k, fragment in enumerate(fragment_of(0, download.transfer_id, calibration.to_bytes())):
        answer = s.feed(board.encode(fragment, flags=Flags.ACK_REQUESTED)[1], 0.04 + 0.01 * k)
        assert answer
        s.feed(answer, 0.041 + 0.01 * k)  # the host's Ack, back
    assert s.commands.stats.unmatched_answers == 0 and s.commands.stats.late_answers == 0
    assert download.result().to_bytes() == calibration.to_bytes()
    assert s.counters.echoes == 2 + len(fragment_of(0, download.transfer_id, calibration.to_bytes()))


def test_a_handshake_only_echoed_says_so_in_its_link_timeout():
    """No board, only an echo: the handshake fails after its tries, its LinkTimeout saying how many of the
    host's frames came back and that the port echoes."""
    s = Session()
    t, out = 0.0, s.link_up(0.0)
    while s.phase is Phase.HANDSHAKING:
        s.feed(out, t + 0.001)
        t = s.next_deadline()
        out = s.poll(t)
    assert isinstance(s.failure, LinkTimeout)
    tries = s.config.handshake.max_tries
    assert f"no answer after {tries} tries); {tries} of the frames the host wrote came back" in str(s.failure)
    assert ECHO_SAID in str(s.failure) and s.counters.echoes == tries and s.last_heard == 0.0


def test_another_hosts_frames_are_told_from_an_echo():
    """Frames only a host sends, not this host's (another host on the line): counted apart, said apart in
    the LinkTimeout, never heard from the board."""
    s = Session()
    t, other = 0.0, Framer(first_seq=77)
    s.link_up(0.0)
    while s.phase is Phase.HANDSHAKING:
        s.feed(other.encode(Hello(model="other host"))[1] + other.encode(setpoint())[1], t + 0.001)
        t = s.next_deadline()
        s.poll(t)
    message = str(s.failure)
    assert "frames only a host sends came from the far side" in message and ECHO_SAID not in message
    assert s.last_heard == 0.0  # never heard from a board
    assert f"; {s.counters.host_frames} frames only a host sends" in message and s.counters.echoes == 0


# ====================================================================== real ptys
@contextmanager
def echoing_pty(tmp: Path) -> Iterator[Path]:
    """A pty (a link to it in ``tmp``) whose far side writes back every byte it reads: a loopback plug."""
    master, slave = os.openpty()
    tty.setraw(slave)
    link = tmp / "loopback"
    link.symlink_to(os.ttyname(slave))
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            if select.select([master], [], [], 0.02)[0]:
                try:
                    data = os.read(master, 4096)
                except OSError:  # nobody has the slave open right now
                    time.sleep(0.01)
                    continue
                os.write(master, data)

    thread = threading.Thread(target=serve, name="loopback", daemon=True)
    thread.start()
    try:
        yield link
    finally:
        stop.set()
        thread.join(timeout=5.0)
        os.close(master)
        os.close(slave)


@contextmanager
def half_duplex(tmp: Path, board_path: str) -> Iterator[tuple[Path, Callable[[], None]]]:
    """A pty (a link to it in ``tmp``) to the board at ``board_path`` through an adapter that also hands
    the host back what it wrote; whole frames at a time each way, as a half-duplex bus carries them. The
    callable cuts the board off (the echo goes on)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    link = tmp / "half-duplex"
    link.symlink_to(os.ttyname(slave))
    board = os.open(board_path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(board)
    stop, cut = threading.Event(), threading.Event()

    def whole_frames(buf: bytearray, data: bytes) -> bytes:
        buf += data
        end = buf.rfind(0) + 1
        out = bytes(buf[:end])
        del buf[:end]
        return out

    def serve() -> None:
        from_host, from_board = bytearray(), bytearray()
        while not stop.is_set():
            ready = select.select([master, board], [], [], 0.02)[0]
            if master in ready:
                try:
                    frames = whole_frames(from_host, os.read(master, 4096))
                except OSError:
                    time.sleep(0.01)
                    continue
                if frames and not cut.is_set():
                    os.write(board, frames)
                os.write(master, frames)  # the echo
            if board in ready:
                frames = whole_frames(from_board, os.read(board, 4096))
                if frames and not cut.is_set():
                    os.write(master, frames)

    thread = threading.Thread(target=serve, name="half-duplex", daemon=True)
    thread.start()
    try:
        yield link, cut.set
    finally:
        stop.set()
        thread.join(timeout=5.0)
        for fd in (master, slave, board):
            os.close(fd)


def settle(until: Callable[[], bool], timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while not until():
        assert time.monotonic() < end, "not there in time"
        time.sleep(0.01)


def test_a_real_board_behind_an_echoing_adapter_runs_then_is_reported_silent(tmp_path):
    """firmware-sim behind a half-duplex adapter that echoes: connect, arm, setpoints move the rotor
    pulse, idle heartbeats come back — no reset, no sequence gap, the echoes counted; then the board is
    cut off while the echo goes on: silence is reported and ``last_heard`` stops."""
    with sims(tmp_path) as started:
        sim = Sim(tmp_path, tmp_path / "board", "--units", str(UNITS), "--telemetry-rate", "20")
        started.append(sim)
        with half_duplex(tmp_path, sim.path) as (link, cut_off):
            client = BoardClient(str(link), config=ClientConfig(silence_after_s=0.5))
            try:
                client.connect(timeout=10.0)
                client.start()
                client.arm(timeout=5.0)
                for _ in range(40):
                    client.send_setpoint(setpoint(400.0))
                    time.sleep(0.02)
                settle(lambda: client.telemetry is not None and client.telemetry.pulses_us[1] > 1000)
                time.sleep(0.5)  # idle: the host's heartbeats go out, and come back
                stats = client.stats()
                assert stats.counters.heartbeats_sent > 0
                assert client.connected and client.state is BoardState.ARMED
                assert stats.counters.resets == 0 and stats.counters.handshakes == 1
                assert stats.counters.echoes >= stats.counters.heartbeats_sent + 40
                assert stats.seq_gaps == 0 and stats.unmatched_answers == 0
                client.drain_events()
                cut_off()
                heard = client.session.last_heard
                settle(lambda: any(isinstance(e, SilenceEvent) for e in client.drain_events()), 5.0)
                assert client.session.last_heard is not None and heard is not None
                assert client.session.last_heard - heard < 0.2  # at most what was already on its way
                assert client.stats().counters.silences == 1
            finally:
                client.close()


@pytest.mark.parametrize("timeout", [None, 1.0], ids=["every-try", "caller-timeout"])
def test_a_client_against_a_loopback_plug_says_the_port_echoes(tmp_path, timeout):
    """BoardClient.connect() on a loopback pty: a LinkTimeout that says the host's frames came back, at
    the handshake's last try or at the caller's ``timeout``."""
    with echoing_pty(tmp_path) as link:
        client = BoardClient(str(link))
        with pytest.raises(LinkTimeout, match=ECHO_SAID):
            client.connect(timeout)
        if timeout is None:
            assert client.stats().counters.echoes == client.config.handshake.max_tries


@pytest.mark.parametrize(
    "argv",
    [
        ["run", "--duration", "1"],
        ["replay", str(SHARED_DATA / "sensorlogger-android")],
        ["calibrate", "esc", "--unit", "0", "--confirm-unloaded"],
    ],
    ids=["run", "replay", "calibrate"],
)
def test_the_tools_say_the_port_echoes(tmp_path, argv):
    """``hil run``, ``hil replay --port`` and ``hil calibrate`` on a loopback plug end with status 2 after
    the handshake's tries, their error saying the port echoes what the host sends; no traceback."""
    out = [] if argv[0] == "calibrate" else ["--out", str(tmp_path / "runs")]
    with echoing_pty(tmp_path) as link:
        code, err = Operated([*argv, "--port", str(link), *out]).finish(60.0)
    assert code == 2 and "Traceback" not in err, err
    assert ECHO_SAID in err.splitlines()[-1], err
