"""The board client against the in-process emulated board in lockstep: the full protocol, simulated time,
no threads. Link faults, MCU hangs and resets come from the board's own fault injector."""

from __future__ import annotations

import hashlib
import math
import time

import pytest

from firmware_sim.servers.transports import EmulatorTransport
from hil.link.board import (
    BoardClient,
    BoardResetEvent,
    ClientConfig,
    ConnectedEvent,
    LinkLostEvent,
    SilenceEvent,
    StateEvent,
    TelemetryEvent,
)
from hil.link.transports import create_transport
from hil.timing.clock import LockstepClock, WallClock
from protocol.calibration import default_unit_calibration
from protocol.errors import (
    BoardReset,
    CommandFailed,
    ConfigError,
    FieldRangeError,
    HandshakeError,
    LinkTimeout,
    ProtocolError,
)
from protocol.messages import (
    SCHEMA_HASH,
    ActuatorSetpoint,
    BoardState,
    ControlMode,
    RawPulses,
    ResetCause,
    UnitSetpoint,
)
from protocol.reliable import RetryPolicy

ROTOR = 1  # pulse channel of unit 0's rotor


def setpoint(speed: float, units: int = 4, gimbal: float = 0.0) -> ActuatorSetpoint:
    return ActuatorSetpoint(units=tuple(UnitSetpoint(gimbal, speed) for _ in range(units)))


def lockstep_client(
    query: str = "units=4&telemetry_rate=50", **config: object
) -> tuple[BoardClient, LockstepClock]:
    clock = LockstepClock()
    client = BoardClient(EmulatorTransport(f"emu://?{query}", clock), config=ClientConfig(**config))  # type: ignore[arg-type]
    return client, clock


def run(
    client: BoardClient,
    clock: LockstepClock,
    seconds: float,
    sp: ActuatorSetpoint | None = None,
    period: float = 0.01,
) -> list[object]:
    """The caller's loop: ``seconds`` of simulated time at ``period``, a setpoint each step."""
    events: list[object] = []
    for _ in range(round(seconds / period)):
        clock.advance(period)
        if sp is not None:
            client.send_setpoint(sp)
        events += client.service()
    return events


def digest(events: list[object]) -> str:
    return hashlib.sha256(repr(events).encode()).hexdigest()


def closed_exchange() -> tuple[str, float, BoardClient]:
    client, clock = lockstep_client()
    info = client.connect()
    assert info.n_units == 4 and info.schema_hash == SCHEMA_HASH
    client.arm()
    slow = run(client, clock, 5.0, setpoint(150.0))
    pulse_slow = client.telemetry.pulses_us[ROTOR]
    fast = run(client, clock, 5.0, setpoint(450.0))
    pulse_fast = client.telemetry.pulses_us[ROTOR]
    assert 1000 < pulse_slow < pulse_fast <= 2000
    client.disarm()
    assert client.state is BoardState.DISARMED
    return digest(slow + fast), clock.now(), client


def test_ten_seconds_of_board_time_in_well_under_a_second_and_deterministic():
    start = time.process_time()  # CPU time: what the run costs, whatever else the machine is doing
    first, t_end, client = closed_exchange()
    cpu = time.process_time() - start
    assert t_end > 10.0
    assert cpu < 1.0, f"10 s of lockstep board time took {cpu:.2f} s of CPU time"
    stats = client.stats()
    assert stats.counters.setpoints_sent == 1000 and stats.bad_frames_total == 0 and stats.failed == 0
    assert stats.board_rx_frames is not None and stats.board_rx_frames >= 1000
    second, _, _ = closed_exchange()
    assert first == second  # same events, same times, same telemetry


def test_telemetry_events_carry_the_host_receive_time_and_the_board_state():
    client, clock = lockstep_client()
    client.connect()
    client.arm()
    events = run(client, clock, 1.0, setpoint(300.0))
    tel = [e for e in events if isinstance(e, TelemetryEvent)]
    assert 45 <= len(tel) <= 55  # 50 Hz
    assert all(e.telemetry.state is BoardState.ARMED for e in tel)
    times = [e.t for e in tel]
    assert times == sorted(times) and times[-1] <= clock.now()
    assert client.telemetry is tel[-1].telemetry and client.telemetry_time == tel[-1].t


def test_an_incompatible_board_is_a_handshake_error_naming_both_sides():
    client, _ = lockstep_client(schema_hash=0x12345678)
    with pytest.raises(HandshakeError) as err:
        client.connect()
    text = str(err.value)
    assert f"{SCHEMA_HASH:#010x}" in text and "0x12345678" in text and "ADK-VSCMG" in text
    board = client.transport.board
    assert board.state is BoardState.BOOT  # the board stayed where it was


def test_a_link_stall_puts_the_board_in_failsafe_and_arm_recovers():
    client, clock = lockstep_client()
    client.connect()
    client.arm()
    run(client, clock, 0.5, setpoint(400.0))
    client.transport.board.faults.stall(0.6)  # the cable is pulled for 0.6 s, from now
    events = run(client, clock, 1.5, setpoint(400.0))
    states = [e.new for e in events if isinstance(e, StateEvent)]
    assert states == [BoardState.FAILSAFE]
    assert client.state is BoardState.FAILSAFE
    assert client.telemetry.pulses_us[ROTOR] == 1000  # rotors at the safe pulse
    client.arm()
    run(client, clock, 0.5, setpoint(400.0))
    assert client.state is BoardState.ARMED
    assert client.telemetry.pulses_us[ROTOR] > 1400


@pytest.mark.parametrize("phase", ["disarmed", "armed", "streaming"])
@pytest.mark.parametrize("at", [0.0, 0.0037, 0.0101, 0.4999])
def test_the_port_closed_under_the_client_is_a_link_loss_it_recovers_from(phase: str, at: float):
    """The port is closed behind the client's back (another part of the host, a test, a hot-unplug that a
    backend reports by closing) at a drawn moment, not inside a read: the client must not sit with a closed
    port and a session it believes is up (a write on a closed port is skipped, so nothing else would tell
    it). One link loss, a reconnect, the same board (no reset), and commands work again."""
    client, clock = lockstep_client()
    client.connect()
    if phase != "disarmed":
        client.arm()
    sp = setpoint(300.0) if phase == "streaming" else None
    run(client, clock, 0.3, sp)
    clock.advance(at)
    client.transport.close()
    events = run(client, clock, 1.0, sp)
    lost = [e for e in events if isinstance(e, LinkLostEvent)]
    back = [e for e in events if isinstance(e, ConnectedEvent)]
    assert len(lost) == 1 and "closed" in lost[0].reason, events[:5]
    assert len(back) == 1 and back[0].t > lost[0].t and back[0].reconnects == 1
    assert not [e for e in events if isinstance(e, BoardResetEvent)]
    assert client.connected and client.transport.is_open
    client.arm()
    run(client, clock, 0.3, setpoint(300.0))
    assert client.state is BoardState.ARMED and client.telemetry_time > clock.now() - 0.1


def test_a_long_stall_is_reported_as_silence_and_its_end():
    client, clock = lockstep_client(silence_after_s=0.5)
    client.connect()
    client.transport.board.faults.stall(1.0)
    events = [e for e in run(client, clock, 2.0) if isinstance(e, SilenceEvent)]
    assert [e.ended for e in events] == [False, True]
    assert 0.45 <= events[0].t - events[0].since <= 0.55
    assert client.stats().counters.silences == 1


def test_an_mcu_hang_is_a_watchdog_reset_reported_with_its_cause():
    client, clock = lockstep_client("units=4&mcu_watchdog=0.3")
    client.connect()
    client.arm()
    run(client, clock, 0.3, setpoint(300.0))
    client.transport.board.faults.hang()
    events = run(client, clock, 1.0)
    resets = [e for e in events if isinstance(e, BoardResetEvent)]
    assert len(resets) == 1
    assert resets[0].cause is ResetCause.WATCHDOG and resets[0].during_session
    assert "uptime went back" in resets[0].evidence or "BOOT" in resets[0].evidence
    assert client.state is BoardState.DISARMED  # handshaken again, not re-armed
    with pytest.raises(BoardReset, match="WATCHDOG"):
        client.send_setpoint(setpoint(300.0))
    with pytest.raises(BoardReset):  # until the caller decides
        client.send_setpoint(setpoint(300.0))
    client.arm()
    run(client, clock, 0.3, setpoint(300.0))
    assert client.state is BoardState.ARMED and client.telemetry.pulses_us[ROTOR] > 1200
    assert client.stats().counters.resets == 1


def test_a_reset_of_a_disarmed_board_is_reported_without_blocking_setpoints():
    client, clock = lockstep_client()
    client.connect()
    run(client, clock, 0.2)
    client.transport.board.reset(ResetCause.EXTERNAL)
    events = run(client, clock, 0.5)
    assert [e.cause for e in events if isinstance(e, BoardResetEvent)] == [ResetCause.EXTERNAL]
    client.send_setpoint(setpoint(100.0))  # nothing needed an armed board: no BoardReset


def test_a_watchdog_reset_before_the_session_is_reported_at_connect():
    clock = LockstepClock()
    transport = EmulatorTransport("emu://?units=2", clock)
    transport.board.reset(ResetCause.WATCHDOG)
    client = BoardClient(transport)
    client.connect()
    resets = [e for e in client.drain_events() if isinstance(e, BoardResetEvent)]
    assert len(resets) == 1 and resets[0].cause is ResetCause.WATCHDOG and not resets[0].during_session


def test_refused_commands_raise_with_the_boards_reason():
    client, clock = lockstep_client()
    client.connect()
    client.arm()
    with pytest.raises(CommandFailed, match="BAD_STATE"):
        client.set_mode(ControlMode.RAW_PULSES)  # modes change only while disarmed
    client.disarm()
    with pytest.raises(FieldRangeError, match="SetMode.mode = 99"):
        client.set_mode(99)  # type: ignore[arg-type]
    client.set_mode(ControlMode.RAW_PULSES)
    client.arm()
    client.send_setpoint(RawPulses(pulses_us=(1500, 1700) * 4))
    run(client, clock, 0.3)
    assert client.telemetry.pulses_us[:2] == (1500, 1700)


def test_setpoints_that_do_not_fit_are_typed_errors_and_nothing_is_sent():
    client, clock = lockstep_client()
    client.connect()
    client.arm()
    sent = client.stats().counters.setpoints_sent
    with pytest.raises(ProtocolError, match="3 units; the board has 4"):
        client.send_setpoint(setpoint(100.0, units=3))
    with pytest.raises(FieldRangeError, match="nan"):
        client.send_setpoint(setpoint(math.nan))
    with pytest.raises(FieldRangeError):
        client.send_setpoint(setpoint(1e6))
    with pytest.raises(ProtocolError, match="channels"):
        client.send_setpoint(RawPulses(pulses_us=(1500,) * 3))
    assert client.stats().counters.setpoints_sent == sent


def test_setpoints_faster_than_the_limit_are_coalesced_newest_wins():
    client, clock = lockstep_client("units=4&frame_rate=50")
    client.connect()
    client.arm()
    board = client.transport.board
    before = board.counters["setpoints"]
    for speed in (100.0, 200.0, 500.0):  # within one slot (2 x 50 Hz -> 10 ms)
        client.send_setpoint(setpoint(speed))
    run(client, clock, 0.3)
    stats = client.stats().counters
    assert stats.setpoints_coalesced == 1
    assert board.counters["setpoints"] - before == 2  # the first, then the newest at its slot
    assert board.command.rotor[0] == 500.0


def test_calibration_upload_and_download_round_trip():
    client, clock = lockstep_client()
    client.connect()
    base = default_unit_calibration()
    assert client.download_calibration(0).to_bytes() == base.to_bytes()
    client.upload_calibration(2, base)
    assert client.download_calibration(2).to_bytes() == base.to_bytes()
    with pytest.raises(ProtocolError, match="unit 7 does not exist"):
        client.download_calibration(7)
    client.arm()
    with pytest.raises(CommandFailed, match="BAD_STATE"):
        client.upload_calibration(1, base)  # only while disarmed


def test_events_reach_the_callback_and_a_full_queue_counts_what_it_drops():
    seen: list[object] = []
    clock = LockstepClock()
    client = BoardClient(
        EmulatorTransport("emu://?units=2&telemetry_rate=100", clock),
        config=ClientConfig(event_queue=10),
        on_event=seen.append,
    )
    client.connect()
    assert client.wait_for(lambda: clock.now() >= 1.0)  # time passes; nobody drains the queue
    kept = client.drain_events()
    assert len(kept) == 10 and kept == seen[-10:]
    assert sum(isinstance(e, TelemetryEvent) for e in seen) >= 90
    assert any(isinstance(e, StateEvent) for e in seen) and any(isinstance(e, ConnectedEvent) for e in seen)
    assert client.stats().counters.events_dropped == len(seen) - 10


def test_configuration_errors():
    with pytest.raises(ConfigError, match="LockstepClock needs the in-process emulator"):
        BoardClient("loop://", clock=LockstepClock())
    with pytest.raises(ConfigError, match="heartbeat_period_s"):
        ClientConfig(heartbeat_period_s=0)
    with pytest.raises(ConfigError, match="reconnect_max_s"):
        ClientConfig(reconnect_first_s=1.0, reconnect_max_s=0.5)
    with pytest.raises(ConfigError, match="event_queue"):
        ClientConfig(event_queue=0)
    transport = EmulatorTransport("emu://", LockstepClock())
    with pytest.raises(Exception, match="another clock"):
        BoardClient(transport, clock=WallClock())
    client, _ = lockstep_client()
    with pytest.raises(ConfigError, match="service"):
        client.start()


def test_a_url_string_gets_the_clients_clock():
    clock = LockstepClock()
    client = BoardClient("emu://?units=2", clock=clock)
    client.connect()
    assert client.transport.board.clock is clock and clock.now() > 0.05
    assert isinstance(create_transport("emu://?units=2"), EmulatorTransport)


def test_a_failed_connect_leaves_the_link_closed_and_can_be_retried():
    clock = LockstepClock()
    transport = EmulatorTransport("emu://?units=2", clock)
    transport.board.faults.stall(1.0)  # nothing crosses the link for the first second
    client = BoardClient(transport, config=ClientConfig(handshake=RetryPolicy(timeout_s=0.1, max_tries=3)))
    with pytest.raises(LinkTimeout, match="did not answer the handshake"):
        client.connect()
    assert not transport.is_open and not client.connected
    assert 0.3 <= clock.now() < 0.5  # three tries, 100 ms apart, then one more timeout
    clock.advance(1.0)
    assert client.connect().n_units == 2
    assert client.stats().counters.link_losses == 0  # never had a session to lose
