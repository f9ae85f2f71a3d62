"""Differential fuzz of the two far sides: the C firmware (on simavr, stepped in lockstep:
``firmware_sim.avr.stepped.FirmwareBoard``) and the Python board (``firmware_sim.board.Board``), fed the
same byte stream from the protocol's real encoder on one clock.

The messages are well-formed but hostile: setpoints at and past every limit (-0.0, float32 subnormals,
the largest and smallest values the codec takes, rates far beyond what a gimbal can do), raw pulses at
the ends of their range, every ``ControlMode``, Arm/Disarm floods interleaved with setpoints, reliable
commands with repeated and out-of-order sequence numbers (with and without ``RETRANSMIT``), calibration
uploads of absurd sets (non-monotonic tables, NaN/∞ coefficients, zero-width ranges, a fragment missing
or repeated), and board configurations at the edges of their ranges. What the codec cannot carry (NaN,
±∞, 1e38 in a setpoint) the real encoder refuses; those go in as hand-built frames, which both boards
must drop as ``field_range`` bad frames that do not even feed the link watchdog.

Invariants, after every step:

* the same answers (Ack/Nack, the Nack's reason, the HelloReply's state) in the same order;
* the same state, mode, fault flags and reported pulse widths (``Telemetry.pulses_us``) once both have
  settled, widths within ``PULSE_TOL_US``: the firmware computes its maps in float32, the emulator in
  double, so a width that lies within float32 rounding of a half-µs boundary may round to the neighbour
  (tests/test_firmware_calibration.py bounds the maps' difference at 0.01 µs);
* no pulse frame on either board outside the range the protocol allows (500..2500 µs) and, whenever the
  board is not ARMED, every rotor channel at the safe pulse: a hostile value never arms or moves a motor;
* neither board crashes or hangs (the harness answers every step; the Python board raises nothing).

ESC endpoint programming (``EscCalibrate``, START and SUPPLY_APPLIED, good fields and bad) runs among the
rest: while it runs its channel is exempt from the safe-pulse rule (it drives that rotor while DISARMED
by design), and telemetry is compared only between the procedure's phase changes (the two boards send
theirs at different moments, and a phase changes the width without any input) - so both report the same
state, mode and widths through the procedure, and the safe pulse as soon as it ends or is aborted.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field, replace

import hypothesis.strategies as st
import pytest
from hypothesis import HealthCheck, given, settings

from firmware_sim.board.config import BoardConfig
from firmware_sim.board.core import Board
from hil.timing.clock import LockstepClock
from protocol.calibration import default_unit_calibration, fragment
from protocol.calibration.codec import HEADER, KNOT
from protocol.crc import crc16_ccitt_false
from protocol.errors import FieldRangeError
from protocol.frame import BadFrame, Deframer, encode_frame, seal
from protocol.messages import (
    ESC_CALIBRATION_CONFIRM,
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    CalibrationData,
    CalibrationRequest,
    ControlMode,
    Disarm,
    EscCalibrate,
    EscCalStep,
    Flags,
    GimbalMode,
    Heartbeat,
    Hello,
    HelloReply,
    Nack,
    RawPulses,
    SetMode,
    Telemetry,
    UnitSetpoint,
)

PULSE_TOL_US = 1
"""Reported widths are whole µs (half up) of a fine width; float32 maps against double ones differ by
far less than 0.01 µs, which can still move a width lying on a half-µs boundary by one."""
ESC_PHASE_MARGIN_MS = 6.0
"""How far apart the two boards' ESC procedure phase changes may lie (ms): the firmware takes a command
in a few ms of line later (115200 baud) and times the phases in whole ms."""
SETTLE_MS = 40
"""Telemetry is compared once both boards sent one at least this long after the last input (ms): the
firmware converts a setpoint over a few main-loop passes, and the two telemetry schedules differ in phase."""
RELIABLE = int(Flags.ACK_REQUESTED)
RETRY = int(Flags.ACK_REQUESTED | Flags.RETRANSMIT)
F32_MAX = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]
F32_TINY = struct.unpack("<f", b"\x01\x00\x00\x00")[0]  # the smallest subnormal float32
F32_MIN_NORMAL = struct.unpack("<f", b"\x00\x00\x80\x00")[0]


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def above(x: float) -> float:
    """The next float32 above ``x`` (a float32)."""
    if x == 0.0:
        return F32_TINY
    bits = struct.unpack("<i", struct.pack("<f", x))[0]
    return struct.unpack("<f", struct.pack("<i", bits + (1 if x > 0 else -1)))[0]


def below(x: float) -> float:
    return -above(-x)


def edges(limit: float, *inner: float) -> list[float]:
    """Hostile values inside ``±limit`` (what the codec carries): the ends, one float32 inside them,
    zeros, subnormals, and each of ``inner`` (a physical limit) and the float32s on either side of it."""
    out = [0.0, -0.0, F32_TINY, -F32_TINY, F32_MIN_NORMAL, limit, -limit, below(limit), above(-limit)]
    for x in inner:
        out += [x, below(x), above(x), -x, below(-x), above(-x)]
    return out


# the gimbal's physical rate (GimbalParams.max_rate_rad_s) and the angle range of the default map; the
# rotor's full speed at a full pack (kv x V) and the default map's ends
GIMBAL_VALUES = edges(100.0, 2.0, 1.0, math.pi, 20.0)
ROTOR_VALUES = edges(2500.0, 600.0, 1200.0, 1e-3, 2000.0)
gimbal_values = st.one_of(st.sampled_from(GIMBAL_VALUES), st.floats(-100, 100, width=32))
rotor_values = st.one_of(st.sampled_from(ROTOR_VALUES), st.floats(-2500, 2500, width=32))
raw_widths = st.one_of(
    st.sampled_from([500, 501, 999, 1000, 1500, 2000, 2001, 2499, 2500]), st.integers(500, 2500)
)


# --------------------------------------------------------------------------- both boards on one clock
@dataclass
class Seen:
    """What one board said: answers in order, and its newest telemetry."""

    answers: list[tuple] = field(default_factory=list)
    telemetry: Telemetry | None = None


class Pair:
    """The firmware and the emulator side by side on one lockstep clock, fed the same bytes."""

    def __init__(self, config: BoardConfig) -> None:
        from firmware_sim.avr.stepped import FirmwareBoard

        self.config = config
        self.clock = LockstepClock()
        self.fw = FirmwareBoard(config, clock=self.clock)
        self.py = Board(config, clock=self.clock)
        self.boards = {"firmware": self.fw, "emulator": self.py}
        self.deframers = {k: Deframer() for k in self.boards}
        self.seen = {k: Seen() for k in self.boards}
        self.frames_checked = {k: 0 for k in self.boards}
        self.seq = 0
        self.last_input_ms = 0.0
        self.compared = 0  # telemetry pairs compared
        self.held_at = -1  # the emulator's setpoint count when its gimbals last held an angle
        self.esc_changes: list[float] = []  # clock ms of the emulator's ESC procedure's phase changes
        self.esc_driven: dict[int, float] = {}  # channel -> the last clock ms the procedure drove it
        self._esc_phase = self.py.esc_calibration.phase

    def close(self) -> None:
        self.fw.close()

    def run(self, dt: float) -> None:
        end = self.clock.now() + dt
        while self.clock.now() < end - 1e-9:
            nxt = min(end, self.clock.now() + 0.01, *(b.next_deadline() for b in self.boards.values()))
            self.clock.set(max(nxt, self.clock.now() + 1e-6))
            for b in self.boards.values():
                b.step()
            self._check_frames()
            self._watch_esc()
        self._drain()

    def _watch_esc(self) -> None:
        """Note the emulator's ESC procedure: when its phase changes, and which channel it drives."""
        esc = self.py.esc_calibration
        now_ms = self.clock.now() * 1e3
        if esc.phase is not self._esc_phase:
            self._esc_phase = esc.phase
            self.esc_changes.append(now_ms)
        taught = esc.rotor_width()
        if taught is not None:
            self.esc_driven[taught[0]] = now_ms

    def feed(self, data: bytes) -> None:
        self.last_input_ms = self.clock.now() * 1e3
        for b in self.boards.values():
            b.feed(data)

    def send(self, msg, flags: int = 0, seq: int | None = None) -> int:
        if seq is None:
            seq, self.seq = self.seq, (self.seq + 1) & 0xFF
        self.feed(encode_frame(msg, seq, flags))
        return seq

    def _drain(self) -> None:
        for k, b in self.boards.items():
            for e in self.deframers[k].feed(b.take_output()):
                assert not isinstance(e, BadFrame), f"{k} sent a bad frame: {e}"
                m = e.message
                if isinstance(m, Ack):
                    self.seen[k].answers.append(("ack", m.msg_id, m.seq))
                elif isinstance(m, Nack):
                    self.seen[k].answers.append(("nack", m.msg_id, m.seq, m.reason.name))
                elif isinstance(m, HelloReply):
                    self.seen[k].answers.append(("hello", m.state.name))
                elif isinstance(m, Telemetry):
                    self.seen[k].telemetry = m

    def _check_frames(self) -> None:
        """Every pulse frame since the last look is within the protocol's 500..2500 µs."""
        for k, b in self.boards.items():
            total = b.timeline.total_frames
            new = min(total - self.frames_checked[k], len(b.timeline.frames))
            self.frames_checked[k] = total
            for fr in list(b.timeline.frames)[len(b.timeline.frames) - new :] if new else []:
                for ch, w in enumerate(fr.widths):
                    assert w is None or 500 <= w <= 2500, f"{k}: channel {ch} at {w} µs at {fr.t:.4f} s"

    def _check_safe(self, now_ms: float) -> None:
        """A board not ARMED has every rotor at the safe pulse: checked once the frames under way when it
        left ARMED (a pulse is never cut short) have ended."""
        frames_ms = 3e3 / self.config.frame_rate_hz + 5.0
        if now_ms - self.last_input_ms < frames_ms or self._near_link_deadline(now_ms - frames_ms, now_ms):
            return
        taught = {ch for ch, t in self.esc_driven.items() if now_ms - t < frames_ms}
        for k, b in self.boards.items():
            last = b.timeline.last()
            if b.state is not BoardState.ARMED and last is not None:
                rotors = [w for ch, w in enumerate(last.widths) if ch % 2 and ch not in taught]
                safe = self.config.rotor_safe_us
                assert all(w in (None, safe) for w in rotors), f"{k} {b.state.name}: rotors {rotors}"

    def compare(self, final: bool = False) -> None:
        """Same answers, same state; after settling, the same telemetry. The firmware's answers may lag
        (its UART runs at the configured baud, the emulator's link has no such limit: a download's
        fragments and telemetry of six units at 50 Hz fill 115200 baud), so until ``final`` they need
        only be a prefix of the emulator's."""
        fw, py = self.seen["firmware"], self.seen["emulator"]
        if final:
            assert fw.answers == py.answers
        else:
            assert fw.answers == py.answers[: len(fw.answers)]
        now_ms = self.clock.now() * 1e3
        self._check_safe(now_ms)
        if not self._near_link_deadline(now_ms, now_ms):
            assert self.fw.state is self.py.state
        if self.py.state is not BoardState.ARMED and self.py.gimbal_mode is GimbalMode.ANGLE:
            self.held_at = self.py.counters["setpoints"]  # the gimbals hold where they are
        a, b = fw.telemetry, py.telemetry
        if a is None or b is None or not (self._settled(a) and self._settled(b)):
            return
        if self._near_link_deadline(min(a.time_ms, b.time_ms), max(a.time_ms, b.time_ms)):
            return  # the two were sent on either side of the link loss
        t0, t1 = (
            min(a.time_ms, b.time_ms) - ESC_PHASE_MARGIN_MS,
            max(a.time_ms, b.time_ms) + ESC_PHASE_MARGIN_MS,
        )
        if any(t0 <= t <= t1 for t in self.esc_changes):
            return  # the two were sent on either side of a phase change of the ESC procedure
        self.compared += 1
        assert (a.state, a.mode, a.watchdog) == (b.state, b.mode, b.watchdog)
        assert a.faults == b.faults, f"faults firmware {a.faults:#x} emulator {b.faults:#x}"
        assert len(a.pulses_us) == len(b.pulses_us)
        for ch, (x, y) in enumerate(zip(a.pulses_us, b.pulses_us, strict=True)):
            spread = self._rotor_spread if ch % 2 else self._gimbal_spread
            tol = PULSE_TOL_US + spread(ch // 2, a, b)
            assert abs(x - y) <= tol, f"channel {ch}: firmware {a.pulses_us} emulator {b.pulses_us}"

    def _settled(self, t: Telemetry) -> bool:
        """Whether ``t`` was sent at least SETTLE_MS after its board handled the last input (its
        ``link_age_ms`` says when that was: a busy firmware takes bytes in late)."""
        handled = t.time_ms - t.link_age_ms
        return t.link_age_ms != 0xFFFF and handled >= self.last_input_ms - 1.5 and t.link_age_ms >= SETTLE_MS

    def _near_link_deadline(self, t0_ms: float, t1_ms: float) -> bool:
        """Whether either board's link timeout falls between ``t0_ms`` and ``t1_ms``, widened by the link
        watchdogs' resolution (the firmware's counts whole 1 ms ticks, the emulator's expires at the exact
        µs). Each board's own timeout runs from when it handled the last frame (its telemetry's
        ``link_age_ms`` says when): a busy firmware takes bytes in late (33 ms after a calibration set
        completes: it validates the set in float32 on a 16 MHz AVR)."""
        handled = [self.last_input_ms]
        for seen in self.seen.values():
            t = seen.telemetry
            if t is not None and t.link_age_ms != 0xFFFF:
                handled.append(t.time_ms - t.link_age_ms)
        timeout = self.config.link_timeout_s * 1e3
        return t0_ms - 4.0 <= max(handled) + timeout and min(handled) + timeout <= t1_ms + 2.0

    def _gimbal_spread(self, unit: int, a: Telemetry, b: Telemetry) -> float:
        """How far apart a gimbal's width may be (µs): ``PULSE_TOL_US``, but for a gimbal held in ANGLE
        mode (by a board not ARMED, or armed again since and given no new setpoint yet). That one holds
        "where it is", and where it is is the firmware's open-loop estimate (Euler steps of actuators.py's
        servo, one per pulse frame) on one board and the emulator's servo model (exact) on the other:
        they agree to a few percent of the angle in a slew, but in a transient (a reversal, the decay to a
        new target at 50 Hz frames) the Euler steps part from the exact solution by up to ~0.06 rad: the
        widths to 25 µs (0.075 rad of the default map) plus 5 % of their distance from 1500 µs."""
        if self.py.gimbal_mode is not GimbalMode.ANGLE:
            return 0.0
        if a.state is not BoardState.ARMED or self.py.counters["setpoints"] == self.held_at:
            return 25.0 + 0.05 * abs(b.pulses_us[2 * unit] - 1500)
        return 0.0

    def _rotor_spread(self, unit: int, a: Telemetry, b: Telemetry) -> float:
        """How far apart a rotor's width may be between the boards (µs): the width depends on the battery
        voltage, which the firmware reads through its 10-bit ADC and filters on its own (float32) and the
        emulator takes from its model, and the two packs' loads differ a little (each board's own motor
        estimates). The map's widths at both boards' voltages, ±0.1 V, bound it."""
        speed = self.py.command.rotor[unit]
        cal = self.py.calibrations[unit]
        if speed == 0.0 or cal is None:
            return 0.0
        lo = min(a.battery_mv, b.battery_mv) / 1e3 - 0.1
        hi = max(a.battery_mv, b.battery_mv) / 1e3 + 0.1
        return abs(cal.rotor_pulse_us(speed, lo).value - cal.rotor_pulse_us(speed, hi).value)


def hello() -> Hello:
    return Hello(schema_hash=SCHEMA_HASH, manufacturer="diff", model="fuzz", serial="D1")


# --------------------------------------------------------------------------- hostile calibration sets
def _mutate_set(data: bytes, offset: int, value: float) -> bytes:
    """The set with the f32 at ``offset`` replaced and its own CRC made good again (so only validation
    can refuse it)."""
    body = bytearray(data[:-2])
    struct.pack_into("<f", body, offset, value)
    return bytes(body) + struct.pack("<H", crc16_ccitt_false(bytes(body)))


def float_offsets(data: bytes) -> list[int]:
    n = sum(data[24:28])
    return [4, 8, 12, 16, 20] + [HEADER.size + KNOT.size * k + 4 * j for k in range(n) for j in range(3)]


HOSTILE_FLOATS = [math.nan, math.inf, -math.inf, -0.0, 0.0, F32_TINY, F32_MAX, -F32_MAX, 1e38, 1500.0, 2500.0]


@st.composite
def hostile_sets(draw) -> bytes:
    data = default_unit_calibration().to_bytes()
    for _ in range(draw(st.integers(0, 3))):
        offset = draw(st.sampled_from(float_offsets(data)))
        value = draw(st.one_of(st.sampled_from(HOSTILE_FLOATS), st.floats(width=32, allow_nan=True)))
        data = _mutate_set(data, offset, value)
    return data


@st.composite
def uploads(draw, n_units: int) -> list[CalibrationData]:
    """One upload, its fragment list possibly broken: a fragment missing, repeated or out of order."""
    unit = draw(st.sampled_from(sorted({0, n_units - 1, n_units, 7})))
    data = draw(hostile_sets())
    parts = fragment(unit, draw(st.integers(0, 255)), data)
    how = draw(st.sampled_from(["whole", "missing", "repeated", "reversed", "alien"]))
    if how == "missing" and len(parts) > 1:
        del parts[draw(st.integers(0, len(parts) - 1))]
    elif how == "repeated":
        k = draw(st.integers(0, len(parts) - 1))
        parts.insert(draw(st.integers(0, len(parts))), parts[k])
    elif how == "reversed":
        parts.reverse()
    elif how == "alien":  # a fragment that contradicts its transfer (count, total_len or CRC)
        k = draw(st.integers(0, len(parts) - 1))
        m = parts[k]
        parts[k] = draw(
            st.sampled_from(
                [
                    replace(m, count=min(m.count + 1, 255)),
                    replace(m, total_len=max(m.total_len - 1, 0)),
                    replace(m, set_crc=m.set_crc ^ 1),
                    replace(m, index=m.count),
                ]
            )
        )
    return parts


# --------------------------------------------------------------------------- the operations
def ops(n_units: int):
    n_ch = 2 * n_units
    units = st.builds(UnitSetpoint, gimbal=gimbal_values, rotor_speed=rotor_values)
    counts = st.one_of(st.just(n_units), st.integers(1, 8))
    setpoint = st.builds(
        lambda mode, us: ("setpoint", ActuatorSetpoint(gimbal_mode=mode, units=tuple(us))),
        st.sampled_from(GimbalMode),
        counts.flatmap(lambda n: st.lists(units, min_size=n, max_size=n)),
    )
    raw = st.builds(
        lambda ws: ("raw", RawPulses(pulses_us=tuple(ws))),
        st.one_of(st.just(n_ch), st.integers(1, 16)).flatmap(
            lambda n: st.lists(raw_widths, min_size=n, max_size=n)
        ),
    )
    esc_units = st.sampled_from(sorted({0, n_units - 1, n_units, 5}))
    esc_start = st.builds(
        EscCalibrate,
        unit=esc_units,
        confirm=st.sampled_from([ESC_CALIBRATION_CONFIRM, ESC_CALIBRATION_CONFIRM, 0]),
        low_us=st.sampled_from([500, 1000, 1100]),
        high_us=st.sampled_from([1400, 1500, 2000, 2500]),
        supply_off_ms=st.sampled_from([0, 100, 150]),
        high_ms=st.sampled_from([100, 150]),
        low_ms=st.sampled_from([100, 150]),
    )
    esc_supply = st.builds(
        EscCalibrate,
        unit=esc_units,
        step=st.just(EscCalStep.SUPPLY_APPLIED),
        confirm=st.just(ESC_CALIBRATION_CONFIRM),
    )
    reliable = st.one_of(
        esc_start,
        esc_supply,
        st.builds(Arm),
        st.builds(Disarm),
        st.builds(SetMode, mode=st.sampled_from(ControlMode)),
        st.builds(
            CalibrationRequest,
            unit=st.sampled_from([0, n_units - 1, n_units, 7]),
            transfer_id=st.integers(0, 255),
        ),
    )
    command = st.tuples(
        st.just("command"),
        st.tuples(
            reliable,
            st.sampled_from([RELIABLE, RELIABLE, RETRY, 0]),
            st.one_of(
                st.none(), st.integers(0, 255)
            ),  # None: the next seq; else drawn (repeats, out of order)
        ),
    )
    return st.one_of(
        setpoint,
        raw,
        command,
        st.just(("repeat", None)),  # the last reliable frame again, byte for byte (a retry)
        st.just(("flood", None)),  # Arm, setpoint, Disarm, setpoint, Arm... in one burst
        st.tuples(st.just("upload"), uploads(n_units)),
        st.just(("hello", None)),
        st.just(("heartbeat", None)),
        st.tuples(st.just("wait"), st.sampled_from([0.002, 0.02, 0.1, 0.3])),  # 0.3 s: the link is lost
    )


CONFIGS = [
    BoardConfig(),
    BoardConfig(
        n_units=1, frame_rate_hz=50.0, rotor_safe_us=1000, link_timeout_s=0.25, esc_supply_switch=True
    ),
    BoardConfig(n_units=6, frame_rate_hz=490.0, rotor_safe_us=1000, telemetry_rate_hz=50.0),
]


STEP_S = 0.103
"""Board time after each step. Not a multiple of a download's retry period (0.1 s): a command repeated k
steps after a download began landed on the very instant its last try was abandoned, a tie the two
boards break on either side of a millisecond tick (the emulator handles a frame when it is fed, the
firmware a millisecond of line later and on whole-ms timers): one said BUSY, the other began a new
download. With at most 12 steps no sum of these steps and the waits falls within a millisecond of it."""


def play(pair: Pair, steps) -> None:
    last_reliable: bytes | None = None
    pair.run(0.15)
    pair.send(hello())
    pair.run(0.1)
    pair.compare()
    n = pair.config.n_units
    for kind, arg in steps:
        if kind in ("setpoint", "raw"):
            pair.send(arg)
        elif kind == "command":
            msg, flags, seq = arg
            seq = pair.send(msg, flags, seq)
            last_reliable = encode_frame(msg, seq, flags)
        elif kind == "repeat" and last_reliable is not None:
            pair.feed(last_reliable)
        elif kind == "flood":
            sp = ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(100.0, 2500.0),) * n)
            for msg in (Arm(), sp, Disarm(), sp, Arm(), Arm(), Disarm(), sp):
                pair.send(msg, RELIABLE if not isinstance(msg, ActuatorSetpoint) else 0)
        elif kind == "upload":
            for m in arg:
                pair.send(m, RELIABLE)
                pair.run(0.004)
        elif kind == "hello":
            pair.send(hello())
        elif kind == "heartbeat":
            pair.send(Heartbeat(time_ms=0, state=0))
        elif kind == "wait":
            pair.run(arg)
        pair.run(STEP_S)
        pair.compare()
    for _ in range(4):  # settle with the link kept alive: the last state must be compared
        pair.send(Heartbeat(time_ms=0, state=0))
        pair.run(0.1)
        pair.compare()
    pair.compare(final=True)
    assert pair.compared


steps_for = {c.n_units: ops(c.n_units) for c in CONFIGS}


@pytest.mark.firmware
@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)
@given(data=st.data())
def test_hostile_sequences_leave_both_boards_alike(data):
    config = data.draw(st.sampled_from(CONFIGS), label="config")
    steps = data.draw(st.lists(steps_for[config.n_units], min_size=1, max_size=12), label="steps")
    pair = Pair(config)
    try:
        play(pair, steps)
    finally:
        pair.close()


# --------------------------------------------------------------------------- what the encoder refuses
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, 1e38, F32_MAX, above(100.0)])
def test_the_encoder_refuses_a_setpoint_the_codec_cannot_carry(value):
    with pytest.raises(FieldRangeError):
        encode_frame(ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(value, 0.0),)), 0)


def _raw_setpoint_frame(gimbal: float, rotor: float, n: int, seq: int) -> bytes:
    """An ActuatorSetpoint built past the encoder: what a broken or hostile sender could put on the wire."""
    payload = bytes([int(GimbalMode.RATE), n]) + struct.pack("<ff", gimbal, rotor) * n
    return seal(struct.pack("<BBBB", 1, ActuatorSetpoint.MSG_ID, seq, 0) + payload)


@pytest.mark.firmware
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, F32_MAX])
def test_a_setpoint_past_the_codec_is_a_bad_frame_on_both_and_moves_nothing(value):
    pair = Pair(BoardConfig())
    try:
        n = pair.config.n_units
        pair.run(0.15)
        pair.send(hello())
        pair.send(Arm(), RELIABLE)
        pair.send(ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(0.0, 100.0),) * n))
        pair.run(0.1)
        pair.compare()
        before = pair.seen["emulator"].telemetry.pulses_us
        assert before[1] > pair.config.rotor_safe_us  # the rotors turn
        for k in range(5):  # 0.1 s of nothing but hostile frames: ignored, the rotors keep their command
            pair.feed(_raw_setpoint_frame(value, value, n, 100 + k))
            pair.feed(_raw_setpoint_frame(0.0, value, n, 100 + k))
            pair.run(0.02)
            pair.compare()
        assert (
            pair.seen["emulator"].telemetry.pulses_us == pair.seen["firmware"].telemetry.pulses_us == before
        )
        pair.run(0.15)  # and they do not feed the link watchdog: FAILSAFE
        pair.compare()
        assert pair.fw.state is pair.py.state is BoardState.FAILSAFE
        for k in pair.boards:
            assert pair.seen[k].telemetry.rx_bad == 10, k
            assert set(pair.seen[k].telemetry.pulses_us[1::2]) == {pair.config.rotor_safe_us}, k
    finally:
        pair.close()


@pytest.mark.firmware
def test_uploads_during_a_six_unit_download_leave_both_boards_alike():
    """What CI drew (seed 87631358515760409256846009740751050585): on six units at 490 Hz, a download,
    its request repeated (BUSY), a refused upload, an upload with a fragment repeated, the request again,
    a SetMode and a Hello. The firmware lost two fragments to a full receive ring (its main loop took
    ~3 bytes/ms against the line's 11.5: tests/test_firmware_rx_keeps_up.py) and answered neither."""
    good = default_unit_calibration().to_bytes()
    steep = _mutate_set(good, HEADER.size + 4 * KNOT.size + 8, -4.7e15)  # a knot slope far outside its box
    unordered = _mutate_set(good, HEADER.size + 8 * KNOT.size, F32_TINY)  # x no longer increasing
    twice = fragment(5, 44, unordered)
    twice.insert(2, twice[1])
    steps = [
        ("command", (CalibrationRequest(unit=0, transfer_id=255), RELIABLE, None)),
        ("repeat", None),
        ("upload", fragment(5, 154, steep)),
        ("upload", twice),
        ("repeat", None),
        ("command", (SetMode(mode=ControlMode.SETPOINT), RELIABLE, None)),
        ("hello", None),
    ]
    pair = Pair(CONFIGS[2])
    try:
        play(pair, steps)
    finally:
        pair.close()


@pytest.mark.firmware
def test_a_hello_after_a_flood_during_a_six_unit_download_is_answered_by_both():
    """What a later draw found (seed 44): on six units, a download under way, a flood, then a Hello. The
    firmware's transmit ring was full of telemetry and download fragments and its HelloReply found no
    room (dropped, counted), where the emulator's 64 KiB took it; what is sent again anyway now leaves
    room for answers (tests/test_firmware_answers_kept.py)."""
    still = ("setpoint", ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(0.0, 0.0),)))
    steps = [
        still,
        ("command", (CalibrationRequest(unit=0, transfer_id=0), RELIABLE, None)),
        still,
        ("flood", None),
        ("hello", None),
        ("command", (Arm(), RELIABLE, None)),
    ]
    pair = Pair(CONFIGS[2])
    try:
        play(pair, steps)
    finally:
        pair.close()
