"""Pulse outputs (protocol.pulses): servo limits and schedule, captured servo pulses, PPM-sum encode and
decode with jitter, the stream decoder's handling of bad trains, and the emulated board's PPM output."""

from __future__ import annotations

import math
import random

import pytest
from conformance.host import lockstep
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.board.config import BoardConfig
from protocol.errors import ConfigError, FieldRangeError, ProtocolError
from protocol.messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    ControlMode,
    Disarm,
    RawPulses,
    SetMode,
    UnitSetpoint,
)
from protocol.pulses import (
    DEFAULT_PPM,
    BadPpm,
    PpmDecoder,
    PpmFrame,
    PpmInterval,
    PpmParams,
    ServoParams,
    decode_ppm,
    encode_ppm,
    measure_servo,
)

SETTINGS = settings(max_examples=60, deadline=None)


# ------------------------------------------------------------------------- servo pulses
@pytest.mark.parametrize(
    ("kwargs", "field", "phrase"),
    [
        ({"min_us": 2000, "max_us": 1000}, "min_us", "below max_us"),
        ({"min_us": 400}, "min_us", "500..2500"),
        ({"max_us": 2600}, "max_us", "500..2500"),
        ({"max_us": 1500.5}, "max_us", "not an integer"),
        ({"frame_rate_hz": 40}, "frame_rate_hz", "outside 50..490"),
        ({"frame_rate_hz": 500}, "frame_rate_hz", "outside 50..490"),
        ({"frame_rate_hz": math.nan}, "frame_rate_hz", "not a finite number"),
        (
            {"max_us": 2100, "frame_rate_hz": 490},
            "frame_rate_hz",
            "does not exceed the longest pulse (2100 µs)",
        ),
    ],
)
def test_servo_params_are_validated_naming_the_field(kwargs, field, phrase):
    with pytest.raises(ConfigError) as info:
        ServoParams(**kwargs)
    assert info.value.where == f"ServoParams.{field}" and phrase in str(info.value)


def test_servo_limits_and_the_fastest_rate():
    p = ServoParams(frame_rate_hz=490)  # 2040 µs > 2000 µs: allowed
    assert p.min_period_us == 2040
    assert ServoParams(min_us=800, max_us=2200, frame_rate_hz=400).min_period_us == 2500
    assert p.check([1000, 1500.4, 2000]) == (1000, 1500, 2000)
    with pytest.raises(FieldRangeError, match=r"servo.channel\[1\] = 2001"):
        p.check([1500, 2001])
    with pytest.raises(FieldRangeError, match=r"channel\[0\]"):
        p.check([math.nan])


@pytest.mark.parametrize("rate", [50.0, 60.0, 333.0, 400.0, 490.0])
def test_the_frame_schedule_is_integer_and_never_drifts(rate):
    p = ServoParams(frame_rate_hz=rate)
    starts = [p.frame_start_us(k) for k in range(0, 100_001, 1)]
    assert all(isinstance(s, int) for s in starts[:10])
    gaps = {b - a for a, b in zip(starts, starts[1:], strict=False)}
    assert gaps <= {math.floor(1e6 / rate), math.ceil(1e6 / rate)}
    assert abs(starts[-1] - 100_000 * 1e6 / rate) < 1.0  # after 100k frames still within a microsecond


@SETTINGS
@given(
    st.lists(st.integers(1000, 2000), min_size=3, max_size=50),
    st.sampled_from([50.0, 100.0, 300.0, 490.0]),
    st.floats(0.0, 2.0),
    st.integers(0, 2**32 - 1),
)
def test_captured_servo_pulses_measure_back(widths, rate, jitter, seed):
    rng = random.Random(seed)
    p = ServoParams(frame_rate_hz=rate)
    pulses = []
    for k, w in enumerate(widths):
        (pulse,) = p.frame(k, [w])
        pulses.append(
            (pulse.rise_us + rng.uniform(-jitter, jitter), pulse.fall_us + rng.uniform(-jitter, jitter))
        )
    got = measure_servo(pulses, p)
    assert all(abs(a - b) <= 2 * jitter + 0.5 for a, b in zip(got.widths_us, widths, strict=True))
    assert got.frame_rate_hz == pytest.approx(rate, rel=1e-3)


@pytest.mark.parametrize(
    ("pulses", "phrase"),
    [
        ([(0.0, 1500.0)], "need at least 2"),
        ([(0.0, 1500.0), (20_000.0, 22_400.0)], "pulse 1 at 20000.0 µs is 2400.0 µs wide"),
        ([(0.0, 1500.0), (20_000.0, 20_300.0)], "300.0 µs wide"),
        (
            [(0.0, 1500.0), (20_000.0, 21_500.0), (30_000.0, 31_500.0)],
            "pulse 2 at 30000.0 µs comes 10000.0 µs after",
        ),
    ],
)
def test_bad_servo_captures_say_which_pulse(pulses, phrase):
    with pytest.raises(ProtocolError, match=phrase):
        measure_servo(pulses, ServoParams())


# ------------------------------------------------------------------------- PPM-sum
def test_encode_ppm_gives_rising_edges_within_one_frame():
    widths = [1000, 1500, 2000, 1200, 1100, 1900, 1300, 1700]
    edges = encode_ppm(widths)
    assert edges == (0.0, 1000.0, 2500.0, 4500.0, 5700.0, 6800.0, 8700.0, 10000.0, 11700.0)
    assert DEFAULT_PPM.frame_us - edges[-1] >= DEFAULT_PPM.min_sync_us
    assert decode_ppm(edges) == tuple(widths)
    assert DEFAULT_PPM.separator_us < DEFAULT_PPM.channel_min_us  # every channel has room for its mark


@pytest.mark.parametrize(
    ("widths", "field"),
    [
        ([1500] * 9, "channels"),
        ([], "channels"),
        ([1500, 2500], r"channel\[1\]"),
        ([600], r"channel\[0\]"),
        ([math.nan], r"channel\[0\]"),
    ],
)
def test_encode_ppm_refuses_what_a_ppm_frame_cannot_carry(widths, field):
    with pytest.raises(FieldRangeError, match=field):
        encode_ppm(widths)


@SETTINGS
@given(
    st.lists(st.integers(800, 2200), min_size=4, max_size=8),
    st.floats(0.0, 25.0),
    st.integers(0, 2**32 - 1),
)
def test_ppm_round_trip_with_jitter(widths, jitter, seed):
    rng = random.Random(seed)
    edges = [e + rng.uniform(-jitter, jitter) for e in encode_ppm(widths)]
    got = decode_ppm(edges)
    assert all(abs(a - b) <= 2 * jitter + 0.5 for a, b in zip(got, widths, strict=True))


@pytest.mark.parametrize(
    ("edges", "phrase"),
    [
        ([0.0, 1000.0, 2000.0], "3 edges = 2 channels; need 4..8"),
        (
            [0.0, 1000.0, 2000.0, 2400.0, 3400.0],
            "channel 2 (edges 2000.0 -> 2400.0 µs) is 400.0 µs, not a channel",
        ),
        ([0.0, 1000.0, 3500.0, 4500.0, 5500.0], "is 2500.0 µs, not a channel (700..2300 µs): gap"),
        ([0.0, 1000.0, 4000.0, 5000.0, 6000.0], "3000.0 µs, not a channel (700..2300 µs): sync"),
        ([0.0, 1000.0, 900.0, 2000.0, 3000.0], "-100.0 µs, not a channel (700..2300 µs): order"),
    ],
)
def test_bad_ppm_frames_are_rejected_saying_where(edges, phrase):
    with pytest.raises(ProtocolError) as info:
        decode_ppm(edges)
    assert phrase in str(info.value)


def _stream(frames, rng, jitter=3.0):
    return [
        k * DEFAULT_PPM.frame_us + e + rng.uniform(-jitter, jitter)
        for k, w in enumerate(frames)
        for e in encode_ppm(w)
    ]


@SETTINGS
@given(
    st.lists(st.lists(st.integers(900, 2100), min_size=8, max_size=8), min_size=3, max_size=12),
    st.integers(0, 2**32 - 1),
    st.integers(1, 40),
)
def test_the_stream_decoder_follows_frames_in_any_chunking(frames, seed, chunk):
    rng = random.Random(seed)
    edges = _stream(frames, rng)
    d = PpmDecoder()
    events = []
    for i in range(0, len(edges), chunk):
        events += d.feed(edges[i : i + chunk])
    # a frame is complete at the next frame's first edge; the first is skipped until a sync is seen
    assert [type(e) for e in events] == [PpmFrame] * (len(frames) - 2)
    for ev, want in zip(events, frames[1:-1], strict=True):
        assert all(abs(a - b) <= 7 for a, b in zip(ev.channels, want, strict=True))
    assert d.counters.frames == len(frames) - 2 and d.counters.dropped == {}


def test_the_stream_decoder_drops_bad_frames_with_a_reason_and_recovers():
    rng = random.Random(7)
    frames = [[1000 + 100 * k] * 8 for k in range(8)]
    edges = _stream(frames, rng, jitter=1.0)
    per = len(encode_ppm(frames[0]))
    glitch = edges[2 * per + 3] + 150.0  # a spike inside frame 2
    edges.insert(2 * per + 4, glitch)
    backwards = edges[4 * per + 2] - 5000.0  # a timestamp from the past inside frame 4
    edges.insert(4 * per + 3 + 1, backwards)
    d = PpmDecoder()
    events = d.feed(edges)
    good = [e for e in events if isinstance(e, PpmFrame)]
    bad = [e for e in events if isinstance(e, BadPpm)]
    assert [e.reason for e in bad] == [PpmInterval.SHORT, PpmInterval.ORDER]
    assert "µs between edges at" in bad[0].detail and "does not come after" in bad[1].detail
    assert d.counters.dropped == {"short": 1, "order": 1}
    firsts = [ev.channels[0] for ev in good]  # frames 1, 3, 5, 6 decode; 2 and 4 are dropped
    assert len(firsts) == 4 and all(
        abs(a - b) <= 2 for a, b in zip(firsts, [1100, 1300, 1500, 1600], strict=True)
    )


def test_too_many_and_too_few_channels_are_dropped():
    d = PpmDecoder(PpmParams(max_channels=8, min_channels=4))
    t = [0.0]
    for step in [3000.0] + [1000.0] * 10 + [3000.0] + [1000.0] * 2 + [3000.0] + [1000.0] * 5 + [3000.0]:
        t.append(t[-1] + step)
    events = d.feed(t)
    assert [getattr(e, "reason", None) for e in events] == ["too_many", "too_few", None]
    assert events[-1].channels == (1000,) * 5


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"separator_us": 800.0}, "channel_min_us"),
        ({"max_channels": 9}, "frame_us"),
        ({"min_channels": 9}, "max_channels"),
        ({"frame_us": -1.0}, "frame_us"),
        ({"min_sync_us": math.inf}, "min_sync_us"),
    ],
)
def test_ppm_params_are_validated(kwargs, field):
    with pytest.raises(ConfigError) as info:
        PpmParams(**kwargs)
    assert info.value.where == f"PpmParams.{field}"


# ------------------------------------------------------------------------- the emulated board's PPM output
def test_the_boards_ppm_output_carries_its_servo_widths_and_clamps_raw_extremes():
    board, clock, host = lockstep(BoardConfig(n_units=4, ppm=True, frame_rate_hz=50.0))
    host.handshake()
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: ActuatorSetpoint(
        units=tuple(UnitSetpoint(0.3 * (i - 1), 100.0 * i) for i in range(4))
    )
    host.poll(0.3)
    train = board.timeline.ppm[-1]
    assert train.t == pytest.approx(clock.now(), abs=0.0226)
    assert decode_ppm(train.edges_us) == board.reported_outputs()[:8]  # whole µs: a PPM receiver's resolution
    host.keepalive = None
    assert isinstance(host.request(Disarm()), Ack)  # the mode changes only while disarmed
    assert isinstance(host.request(SetMode(mode=ControlMode.RAW_PULSES)), Ack)
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: RawPulses(pulses_us=(2500, 500, 1500, 1500, 1500, 1500, 1500, 1500))
    host.poll(0.2)
    assert board.outputs[:2] == (2500, 500)  # the servo outputs pass raw widths through ...
    assert decode_ppm(board.timeline.ppm[-1].edges_us)[:2] == (2300, 700)  # ... the PPM stage clamps them


def test_the_ppm_train_keeps_its_22_5_ms_schedule_while_the_mcu_hangs():
    """Like the per-channel frames, the PPM train is a hardware timer: a hung main loop does not stop it."""
    board, clock, host = lockstep(BoardConfig(n_units=4, ppm=True, frame_rate_hz=50.0, mcu_watchdog_s=0.5))
    host.handshake()
    assert isinstance(host.request(Arm()), Ack)
    t_hang = clock.now() + 0.01
    board.faults.hang(at=t_hang)
    host.poll(0.4)
    during = [train.t for train in board.timeline.ppm if train.t > t_hang + 0.001]
    assert len(during) >= 15
    assert max(abs(b - a - 0.0225) for a, b in zip(during, during[1:], strict=False)) < 1e-6
