"""Board conformance through a real serial port (pyserial on a pty), for every target in TARGETS.

Timing is asserted on the board's clock (``Telemetry.time_ms``, heartbeats, the target's pulse timeline
and reset log), never on host wall time: a slow host changes when bytes arrive, not what the board did.
The host's own waits run on the board's clock too (``conformance.host.connect``), and what followed an
event is read from what the board sent after it, not from whatever arrives first after the host looks.
"""

from __future__ import annotations

import itertools
import math

import pytest

from conformance.host import connect, heartbeat, retry_if_starved
from conformance.targets import timeline_through, uptime_origin
from firmware_sim.board.timeline import PulseFrame
from protocol.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    ControlMode,
    Disarm,
    FaultFlag,
    GimbalMode,
    Heartbeat,
    Hello,
    PowerState,
    RawPulses,
    ResetCause,
    SetMode,
    Telemetry,
    UnitSetpoint,
    WatchdogState,
)

MAIN_LOOP_S = 0.008
"""How long after an event the C firmware's main loop may act on it: its passes take a few ms when
telemetry, the power model and a calibration conversion fall together (measured under simavr)."""


def setpoint(spec, gimbal=0.3, speed=300.0):
    return ActuatorSetpoint(
        gimbal_mode=GimbalMode.RATE,
        units=tuple(UnitSetpoint(gimbal * (-1) ** i, speed + 20.0 * i) for i in range(spec.n_units)),
    )


def armed_and_streaming(target, host, sp, seconds=0.4):
    host.handshake()
    host.keepalive = heartbeat
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: sp
    host.stream(seconds)


def telemetry(host, timeout=1.0, **where):
    return host.wait_type(Telemetry, timeout, lambda m: all(getattr(m, k) == v for k, v in where.items()))


def telemetry_made_since(target, host, since: float, timeout: float = 1.0, **where) -> Telemetry:
    """The first Telemetry (matching ``where``) the board made at or after its time ``since``. One that
    arrives now may have been made long before: on a loaded machine a real-time target's output waits in
    its bridge and the pty (a CI run's first ARMED telemetry after a 1 s stream had been made before the
    stream's first setpoint reached the board: its frames were the hold's)."""
    origin = uptime_origin(target.resets(), target.now())

    def match(m) -> bool:
        return (
            isinstance(m, Telemetry)
            and origin + m.time_ms / 1000 >= since
            and all(getattr(m, k) == v for k, v in where.items())
        )

    return host.wait_for(match, timeout, f"a Telemetry made since {since:.3f} s")


def test_handshake(target, host):
    reply = host.handshake()
    spec = target.spec
    assert (reply.protocol_version, reply.schema_hash) == (PROTOCOL_VERSION, SCHEMA_HASH)
    assert reply.reset_cause == ResetCause.POWER_ON
    assert reply.state == BoardState.DISARMED
    assert (reply.n_units, reply.frame_rate_hz) == (spec.n_units, round(spec.frame_rate_hz))
    assert reply.manufacturer and reply.model and reply.version and reply.serial
    host.keepalive = heartbeat
    tel = telemetry(host, state=BoardState.DISARMED)
    assert tel.pulses_us[1::2] == (spec.rotor_safe_us,) * spec.n_units
    assert len(tel.units) == spec.n_units


def test_arm_and_setpoints_give_the_expected_pulse_widths(target, host):
    spec = target.spec
    tol = spec.pulse_tolerance_us
    sp = setpoint(spec)
    host.handshake()
    host.keepalive = lambda: sp  # setpoints before arming move nothing
    host.stream(0.2)
    tel = telemetry(host)
    assert tel.state == BoardState.DISARMED and tel.pulses_us[1::2] == (spec.rotor_safe_us,) * spec.n_units
    host.keepalive = heartbeat
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: sp
    host.stream(0.5)
    tel = telemetry(host, state=BoardState.ARMED)
    volts = tel.battery_mv / 1000
    for i, u in enumerate(sp.units):
        cal = target.calibration(i)
        g = cal.gimbal_pulse_us(u.gimbal, GimbalMode.RATE).value
        assert abs(tel.pulses_us[2 * i] - g) <= tol + 0.5
        r = [cal.rotor_pulse_us(u.rotor_speed, volts + dv).value for dv in (-0.1, 0.1)]
        assert min(r) - tol - 0.5 <= tel.pulses_us[2 * i + 1] <= max(r) + tol + 0.5
    # The pulse hardware itself: the timeline's frames around that telemetry carry the same widths.
    t_tel = uptime_origin(target.resets(), target.now()) + tel.time_ms / 1000
    frames = [f for f in target.timeline() if t_tel - 0.05 <= f.t <= t_tel]
    assert frames and all(
        all(abs(w - p) <= tol for w, p in zip(f.widths, tel.pulses_us, strict=True)) for f in frames
    )
    host.keepalive = heartbeat
    assert isinstance(host.request(Disarm()), Ack)
    tel = telemetry(host, state=BoardState.DISARMED)
    assert tel.pulses_us[1::2] == (spec.rotor_safe_us,) * spec.n_units


def frames_before(target, tel: Telemetry, seconds: float) -> list[PulseFrame]:
    """The pulse frames of the ``seconds`` before the board sent ``tel`` (its timeline), at least 35 % of
    the frames that span holds, less one in eight (a timeline with a hole is a failure, not a shorter
    average)."""
    t_tel = uptime_origin(target.resets(), target.now()) + tel.time_ms / 1000
    frames = [f for f in timeline_through(target, t_tel) if t_tel - seconds <= f.t <= t_tel]
    assert len(frames) >= 0.875 * seconds * target.spec.frame_rate_hz, len(frames)
    return frames


def assert_dithered(widths: list[float], want: float, slack_us_per_frame: float) -> float:
    """``widths`` (µs, one a frame) dither ``want`` µs over the two neighbouring 0.5 µs ticks, both used, and
    add up to it within one tick (plus ``slack_us_per_frame`` for the calibration's rounding a frame).
    Returns the lower tick."""
    low = math.floor(2 * want) / 2
    assert set(widths) == {low, low + 0.5}, (want, sorted(set(widths)))
    assert abs(sum(widths) - len(widths) * want) <= 0.5 + slack_us_per_frame * len(widths), (want, widths)
    return low


def test_widths_finer_than_a_tick_are_dithered_over_frames(target, host):
    """A calibration map asks for widths between the timers' 0.5 µs ticks: the board puts out whole ticks
    and carries the rest to the next frame, so any run of frames adds up to the width asked for within
    one tick. Gimbal rates far below one tick's worth (~3·10⁻³ rad/s past the dead zone) still move the
    gimbal on average: 1510 µs (the dead zone's edge, rate 0) some frames, 1510.5 µs the others."""
    spec = target.spec
    rates = tuple(1e-3 * (i + 1) * (-1) ** i for i in range(spec.n_units))  # 1, -2, 3, -4 ·10⁻³ rad/s
    sp = ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=tuple(UnitSetpoint(r, 300.0) for r in rates))
    armed_and_streaming(target, host, sp, seconds=1.0)
    tel = telemetry_made_since(target, host, target.now(), state=BoardState.ARMED)
    frames = frames_before(target, tel, 0.4)
    for i, rate in enumerate(rates):
        cal = target.calibration(i)
        want = cal.gimbal_pulse_us(rate, GimbalMode.RATE).value  # e.g. 1510.15 µs
        widths = [f.widths[2 * i] for f in frames]
        low = assert_dithered(widths, want, slack_us_per_frame=1e-4)
        mean_rate = sum(cal.gimbal_value(w, GimbalMode.RATE).value for w in widths) / len(widths)
        step = (
            cal.gimbal_value(low + 0.5, GimbalMode.RATE).value - cal.gimbal_value(low, GimbalMode.RATE).value
        )
        assert abs(mean_rate - rate) <= abs(step) / len(widths) + 0.02 * abs(rate)
        assert tel.pulses_us[2 * i] == math.floor(want + 0.5)  # the wire reports the mean width in whole µs


def test_the_dither_holds_when_a_new_width_comes_every_frame(target, host):
    """A closed loop sends a new setpoint each control tick, as often as the frames go out (a 50 Hz host at
    50 Hz frames): the width changes every frame, by a hair. The firmware wrote each new width to its
    timer undithered (the fraction of a tick lost on every such frame), so widths just past the servo's
    dead zone came out at its edge, rate 0, frame after frame — a held gimbal never moved and the host's
    loop wound up against it (issue 32: the firmware's closed loop did not settle). Every run of frames
    still adds up to the widths asked for within one tick."""
    spec = target.spec
    rates = tuple(1e-3 * (i + 1) * (-1) ** i for i in range(spec.n_units))
    sent = itertools.count()

    scales = (1.0, 1.05)  # a few 1/512 µs apart: the same ticks, another fraction

    def changing() -> ActuatorSetpoint:
        scale = scales[next(sent) % 2]
        return ActuatorSetpoint(
            gimbal_mode=GimbalMode.RATE, units=tuple(UnitSetpoint(r * scale, 300.0) for r in rates)
        )

    host.keepalive_period = 0.5 / spec.frame_rate_hz  # more than one new width a frame
    host.handshake()
    host.keepalive = heartbeat
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = changing
    host.stream(1.0)
    tel = telemetry_made_since(target, host, target.now(), state=BoardState.ARMED)
    frames = frames_before(target, tel, 0.4)
    for i, rate in enumerate(rates):
        cal = target.calibration(i)
        want = sum(cal.gimbal_pulse_us(rate * k, GimbalMode.RATE).value for k in scales) / 2
        assert_dithered([f.widths[2 * i] for f in frames], want, slack_us_per_frame=0.01)


def test_raw_pulses_are_output_exactly(target, host):
    spec = target.spec
    raw = tuple(1100 + 37 * ch for ch in range(2 * spec.n_units))
    host.handshake()
    host.keepalive = heartbeat
    assert isinstance(host.request(SetMode(mode=ControlMode.RAW_PULSES)), Ack)
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: RawPulses(pulses_us=raw)
    host.stream(0.3)
    tel = telemetry(host, state=BoardState.ARMED, mode=ControlMode.RAW_PULSES)
    assert tel.pulses_us == raw
    last = target.timeline()[-1]
    assert all(abs(w - p) <= spec.pulse_tolerance_us for w, p in zip(last.widths, raw, strict=True))


def steady_and_armed(host, steady_s=0.3, timeout=5.0):
    """Stream on until the board has been ARMED with the link up and the same pulse widths for
    ``steady_s`` of board time; that last Telemetry, or None if it never was within ``timeout`` s.

    Rotor widths follow the battery voltage while the rotors spin up (the calibration's voltage
    compensation). On a loaded machine a host on a real-time board can be left unscheduled past the link
    timeout while it streams: the board then fails safe (rightly), and this returns None."""
    end = host.now() + timeout
    widths, since = None, 0
    while host.now() < end:
        tel = telemetry(host)
        if tel.state != BoardState.ARMED or tel.watchdog != WatchdogState.OK:
            return None
        if tel.pulses_us != widths:
            widths, since = tel.pulses_us, tel.time_ms
        elif tel.time_ms - since >= steady_s * 1000:
            return tel
    return None


def silence_after_a_steady_stream(target, host, sp, tries=10):
    """Arm, stream ``sp`` until the board is steady, go quiet; the Telemetry reporting the link loss and
    the FAILSAFE state-change Heartbeat that followed that silence. The test is about the board's answer
    to the host's silence, so the host must have kept the link up until it went quiet: an attempt in
    which it did not (see :func:`steady_and_armed`; only a real-time target) is made again, from arming —
    as is one in which the board's first report of the link loss says a frame had just arrived: a loaded
    machine held the host's last frames up on their way to a real-time board, past the timeout."""
    timeout_ms = target.spec.link_timeout_s * 1000
    tel = None
    for _ in range(tries):
        start = len(host.received)
        armed_and_streaming(target, host, sp)
        steady = steady_and_armed(host)
        host.keepalive = None  # the host goes quiet
        if steady is None:
            continue
        tel = telemetry(host, timeout=2.0, state=BoardState.FAILSAFE, watchdog=WatchdogState.LINK_LOST)
        if tel.link_age_ms < timeout_ms - 1:
            continue
        beat = next(
            m
            for m in host.received[start:]
            if isinstance(m, Heartbeat) and m.state == BoardState.FAILSAFE and m.time_ms >= steady.time_ms
        )
        return tel, beat
    raise AssertionError(
        f"the host could not keep the link up while streaming in {tries} attempts (the last report: {tel})"
    )


@pytest.mark.link_watchdog
def test_link_loss_failsafe_within_timeout_plus_one_frame(target, host):
    spec = target.spec
    tel, beat = silence_after_a_steady_stream(target, host, setpoint(spec, speed=400.0))
    assert tel.watchdog == 1 and tel.faults & FaultFlag.LINK_LOST
    origin = uptime_origin(target.resets(), target.now())
    t_last = origin + (tel.time_ms - tel.link_age_ms) / 1000  # board time of the last frame it took
    t_failsafe = origin + beat.time_ms / 1000
    ms = 0.0015  # the wire carries milliseconds
    frame = 1.0 / spec.frame_rate_hz
    # The board notices on its next main-loop pass: the emulator's 1 ms tick; the ATmega's passes reach a
    # few ms when telemetry, the power model and a calibration conversion fall together (measured under
    # simavr: 251 ms typically, 255 ms at worst in ~20 runs), so its tick interrupt stops the rotors in
    # the tick the link times out. The requirement is timeout + one frame: the safe width takes effect
    # at the next frame start (the compare registers are double-buffered: no pulse is cut short or
    # stretched on the way; simavr: 251.4-260.4 ms in 30 runs).
    assert spec.link_timeout_s - ms <= t_failsafe - t_last <= spec.link_timeout_s + frame + ms
    rotor = [(f.t, f.widths[1]) for f in timeline_through(target, t_failsafe + frame) if f.t >= t_last - 0.1]
    moving = [w for t, w in rotor if t < t_last]
    assert moving and moving[-1] > spec.rotor_safe_us
    t_safe = next(t for t, w in rotor if t >= t_last and w == spec.rotor_safe_us)
    # the last setpoint's width goes on until then: dithered over two neighbouring 0.5 µs ticks, and
    # following the battery voltage (the calibration's voltage compensation; the rotors may still be
    # drawing their spin-up current), so within 1 µs of the last frame before the silence
    assert all(abs(w - moving[-1]) <= 1.0 for t, w in rotor if t_last <= t < t_safe)
    assert spec.link_timeout_s - ms <= t_safe - t_last <= spec.link_timeout_s + frame + ms
    # Setpoints alone never leave FAILSAFE; an Arm does.
    host.keepalive = lambda: setpoint(spec, speed=400.0)
    host.stream(0.3)
    assert telemetry(host).state == BoardState.FAILSAFE
    ack = host.request(Arm())
    assert isinstance(ack, Ack)
    after = host.first_after(ack, Telemetry)  # the board's next report, within a telemetry period
    assert after.state == BoardState.ARMED and after.watchdog == 0


def test_hang_gives_a_watchdog_reset_reported_on_reconnect(target, host):
    spec = target.spec
    armed_and_streaming(target, host, setpoint(spec))
    t_hang = target.inject_hang()
    host.wait_type(Heartbeat, spec.mcu_watchdog_s + 2.0, lambda m: m.state == BoardState.BOOT)
    reset = target.resets()[-1]
    assert reset.cause == ResetCause.WATCHDOG
    # The reset comes mcu_watchdog after the main loop's last check-in, to the millisecond; the main loop
    # stops on the pass after the self-test pin went low (simavr: 500.0-503.0 ms in 30 runs).
    assert spec.mcu_watchdog_s - 0.002 <= reset.t - t_hang <= spec.mcu_watchdog_s + MAIN_LOOP_S
    frames = timeline_through(target, target.now())
    before = [f for f in frames if f.t <= t_hang][-1]
    # Timers (and the frame interrupt's dither) run on at the last targets: within a 0.5 µs tick of them,
    # once the main loop has stopped. Its last pass may still set new ones (the rotors' widths follow the
    # battery voltage while they spin up), so the frames from a pass and a frame after the hang on.
    hung = [f for f in frames if t_hang + MAIN_LOOP_S + 1.0 / spec.frame_rate_hz < f.t < reset.t]
    assert hung and all(
        abs(w - b) <= 0.5 for f in hung for w, b in zip(f.widths, hung[0].widths, strict=True)
    )
    assert all(len({f.widths[ch] for f in hung}) <= 2 for ch in range(len(before.widths)))
    assert all(abs(w - b) <= 1.0 for w, b in zip(hung[0].widths, before.widths, strict=True))
    after = [f for f in frames if f.t > reset.t]
    assert after and after[0].widths[1::2] == (spec.rotor_safe_us,) * spec.n_units
    host.keepalive = None
    host.reopen()  # a host reconnecting after losing its board
    reply = host.handshake()
    assert reply.reset_cause == ResetCause.WATCHDOG and reply.state == BoardState.DISARMED
    host.keepalive = heartbeat
    assert telemetry(host).faults & FaultFlag.MCU_WATCHDOG_RESET


def test_battery_sag_sheds_load_then_browns_out(target, host):
    spec = target.spec
    armed_and_streaming(target, host, setpoint(spec, gimbal=0.0, speed=450.0), seconds=1.0)
    start = len(host.received)
    target.inject_sag(drop_v=9.0, ramp_s=2.0, duration_s=2.6)
    host.wait_type(Heartbeat, 5.0, lambda m: m.state == BoardState.BOOT)
    got = host.received[start:]
    tels = [m for m in got if isinstance(m, Telemetry)]
    first: dict[PowerState, int] = {}
    for m in tels:
        first.setdefault(PowerState(m.power), m.time_ms)
    assert first[PowerState.WARN] < first[PowerState.LIMIT] < first[PowerState.SHED]
    shed = [m for m in tels if m.time_ms >= first[PowerState.SHED] + 30]
    assert shed and all(m.pulses_us[1::2] == (spec.rotor_safe_us,) * spec.n_units for m in shed)
    assert all(m.faults & FaultFlag.BATTERY_LOW for m in shed)
    assert target.resets()[-1].cause == ResetCause.BROWN_OUT
    host.keepalive = None
    host.reopen()
    reply = host.handshake(timeout=0.2)
    assert reply.reset_cause == ResetCause.BROWN_OUT


@pytest.mark.link_watchdog  # the damaged link must keep the watchdog fed
def test_a_link_with_one_percent_corrupted_bytes_still_carries_the_exchange(target, host):
    spec = target.spec
    target.inject_link_noise(corrupt=0.01)
    sp = setpoint(spec)
    host.keepalive_period = 0.02

    def attempt() -> None:
        host.keepalive = None
        host.handshake(tries=50)
        host.keepalive = heartbeat
        assert isinstance(host.request(Arm(), tries=50), Ack)
        host.keepalive = lambda: sp
        host.stream(1.0)
        tel = telemetry(host, timeout=2.0, state=BoardState.ARMED)
        cal = target.calibration(0)
        g = cal.gimbal_pulse_us(sp.units[0].gimbal, GimbalMode.RATE).value
        assert abs(tel.pulses_us[0] - g) <= spec.pulse_tolerance_us + 0.5
        assert host.damage_seen() > 0  # damage reached the host ...
        later = telemetry(host, timeout=2.0)
        # ... and the board, where 1 % per byte costs about a third of the 42-byte setpoint frames, no more.
        assert later.rx_bad > 0 and later.rx_frames > later.rx_bad
        assert later.state == BoardState.ARMED  # the link watchdog never tripped

    # A host left unscheduled for half the link timeout (or its bytes held up by the machine as long on
    # the way to a real-time board), not the damage, would trip it: made again then.
    retry_if_starved(host, attempt, within=spec.link_timeout_s / 2, board=True)


def torn_frame(host):
    """A frame long enough to take several CAN FD segments, for a host to die while sending it."""
    hello = Hello(schema_hash=SCHEMA_HASH, manufacturer="tests", description="d" * 48, serial="T1")
    return host.framer.encode(hello)[1]


def test_a_vanished_host_never_crashes_the_board(target, host):
    spec = target.spec
    armed_and_streaming(target, host, setpoint(spec))
    host.send_torn(torn_frame(host))  # half a frame, then the host is gone
    host.close()
    target.idle(0.4)
    target.check()
    for _ in range(3):  # hosts come and go, some mid-frame
        h = connect(target)
        h.handshake()
        h.send_torn(torn_frame(h))
        h.close()
        target.check()
    again = connect(target)
    try:
        reply = again.handshake()
        assert reply.reset_cause == ResetCause.POWER_ON  # no reset happened along the way
        again.keepalive = heartbeat
        assert telemetry(again).state == BoardState.DISARMED
    finally:
        again.close()
    assert math.isfinite(target.now())


def test_the_boards_time_stamps_never_go_back_within_a_boot(target, host):
    """Heartbeats and telemetry carry the board's uptime; between two boots it never goes back, or the
    host takes the board for one that reset. The C firmware once stamped a state change's heartbeat with
    a fresh clock read and the same pass's telemetry with the pass's start, 1 ms earlier (a closed-loop
    run through the firmware saw "its uptime went back from 4453 ms to 4452 ms": a false reset)."""
    sp = setpoint(target.spec)
    armed_and_streaming(target, host, sp, seconds=0.5)
    for _ in range(3):  # state changes (each with its heartbeat) between telemetry frames
        host.keepalive = heartbeat
        assert isinstance(host.request(Disarm()), Ack)
        host.stream(0.15)
        assert isinstance(host.request(Arm()), Ack)
        host.keepalive = lambda: sp
        host.stream(0.15)
    stamps = [m.time_ms for m in host.received if isinstance(m, (Heartbeat, Telemetry))]
    assert len(stamps) > 20
    back = [(a, b) for a, b in zip(stamps, stamps[1:], strict=False) if b < a]
    assert not back, f"the board's uptime went back: {back[:5]}"


def test_both_ends_count_the_same_link(target, host):
    """The board side's statistics (``ServerStats``, the same type on every transport) against the
    host's own counts: every byte and frame the host sent arrived, every frame the board sent reached the
    host whole, nothing was lost or damaged on the way; and where the target tracks who is on the link,
    the host's arrival, departure (a silence of ``HOST_SILENCE_S``) and return."""
    from firmware_sim.servers.base import HOST_SILENCE_S

    spec = target.spec
    armed_and_streaming(target, host, setpoint(spec), seconds=0.5)
    host.keepalive = heartbeat
    telemetry(host)
    host.poll(0.05)
    stats = target.stats
    if target.lockstep:  # a real-time board may still be taking in the last bytes: they are on their way
        assert (stats.bytes_in, stats.frames_in) == (host.bytes_sent, host.frames_sent)
    else:
        assert stats.frames_in <= host.frames_sent and stats.bytes_in <= host.bytes_sent
    counters = host.deframer.counters
    # one check each, so that a failure says which count moved: the host's damaged frames, the board's
    # link errors, or the board's output dropped at a full line (which the host would see damaged too)
    assert counters.bad_total == 0, (counters, stats)
    assert stats.errors == 0, stats
    assert stats.dropped_out == 0, stats
    if target.lockstep:
        assert stats.bytes_out == host.bytes_received and stats.frames_out == counters.frames
    else:
        assert stats.frames_out >= counters.frames
    if not target.reports_host_presence:
        return
    assert stats.host_present and (stats.host_gone, stats.reconnects) == (0, 0)
    host.keepalive = None
    host.close()
    target.idle(HOST_SILENCE_S + 0.1)
    assert not target.stats.host_present and target.stats.host_gone == 1
    again = connect(target)
    try:
        again.handshake()
        assert target.stats.host_present and target.stats.reconnects == 1
    finally:
        again.close()


def test_the_boot_id_is_drawn_at_every_boot_and_kept_within_one(target, host):
    """Every board announces a boot id: nonzero, the same in its HelloReply and in every Heartbeat of that
    boot (a new session is no new boot), another after a reset — a watchdog reset here, the one every
    target can be made to do — in the BOOT heartbeat and in the answer to the reconnecting host. The host
    tells a board that restarted from the one it had by this alone (hil/link/board/session.py)."""
    spec = target.spec
    reply = host.handshake()
    assert reply.boot_id != 0
    host.keepalive = heartbeat
    host.stream(0.7)  # a few heartbeats (5 Hz) and a second handshake: the same boot
    assert host.handshake().boot_id == reply.boot_id
    host.stream(0.5)
    beats = [m for m in host.received if isinstance(m, Heartbeat)]
    assert len(beats) >= 4 and {b.boot_id for b in beats} == {reply.boot_id}
    target.inject_hang()
    boot = host.wait_type(Heartbeat, spec.mcu_watchdog_s + 2.0, lambda m: m.state == BoardState.BOOT)
    assert target.resets()[-1].cause == ResetCause.WATCHDOG
    assert boot.boot_id not in (0, reply.boot_id)
    host.keepalive = None
    host.reopen()  # a host reconnecting after losing its board
    again = host.handshake()
    assert again.reset_cause == ResetCause.WATCHDOG and again.boot_id == boot.boot_id
    host.keepalive = heartbeat
    host.stream(0.5)
    after = [m for m in host.received if isinstance(m, Heartbeat) and m.state != BoardState.BOOT][-2:]
    assert after and {b.boot_id for b in after} == {boot.boot_id}
