"""An Arm starts the rotors from rest: until a setpoint after it, no rotor channel carries more than the
zero-speed width, however fast the rotors ran before the Disarm, Hello or link loss — for every target.

The C firmware once re-armed at the old speed (found by review): leaving ARMED zeroed the rotor command,
but its rotor conversions are cached and not refreshed while the motors are off (``app.c``:
``convert_step``, ``armed_converting``), so the width cached for the speed before the Disarm stayed
valid, and after the next Arm ``compute_outputs`` used it until the zero command had been converted: the
rotors went out at up to 2000 µs (full throttle) for one to five pulse frames. Leaving ARMED and a new Arm
now forget the cached rotor widths (``stop_rotors``): the safe pulse until the zero command is converted.
The Python board's conversion cache is keyed by the command itself and never had the flaw.

Drawn: the speed before, the way out of ARMED (Disarm or Hello; the link-loss FAILSAFE in its own test),
the pause before the new Arm. Judged on the target's pulse record from the Arm on.
"""

from __future__ import annotations

import random

import pytest

from conformance.host import heartbeat
from conformance.targets import timeline_through
from conformance.test_conformance import armed_and_streaming, setpoint, silence_after_a_steady_stream
from protocol.messages import Ack, Arm, BoardState, Disarm, Heartbeat

WATCH_S = 0.12  # pulse frames judged after the Arm: the reviewer saw the old width for up to 5 frames


def _zero_speed_limit(target) -> float:
    """The highest rotor width (µs) an armed board commanded to zero speed may put out."""
    spec = target.spec
    zero = max(
        target.calibration(u).rotor_pulse_us(0.0, v).value for u in range(spec.n_units) for v in (10.0, 16.8)
    )
    return max(float(spec.rotor_safe_us), zero) + spec.pulse_tolerance_us


def _arm_from_rest(target, host) -> None:
    """Arm (no setpoint follows) and judge the rotor widths of the frames that began from then on."""
    limit = _zero_speed_limit(target)
    host.keepalive = heartbeat
    t_arm = target.now()
    start = len(host.received)
    assert isinstance(host.request(Arm()), Ack)
    host.poll(WATCH_S)
    assert any(isinstance(m, Heartbeat) and m.state == BoardState.ARMED for m in host.received[start:])
    frames = [f for f in timeline_through(target, t_arm + WATCH_S) if f.t >= t_arm]
    assert frames, f"{target.name}: no pulse frame after the Arm"
    fast = [f for f in frames if any((w or 0) > limit for w in f.widths[1::2])]
    assert not fast, (
        f"{target.name}: {len(fast)} frames after a zero-speed Arm carry a rotor above {limit} µs, the first"
        f" at +{fast[0].t - t_arm:.4f} s: {fast[0].widths}"
    )


def test_an_arm_after_disarm_or_hello_starts_the_rotors_from_rest(target, host):
    rng = random.Random(0x5EA7)
    host.handshake()
    host.keepalive = heartbeat
    for cycle in range(5):
        speed = rng.uniform(350.0, 800.0)
        armed_and_streaming(target, host, setpoint(target.spec, speed=speed), seconds=0.25)
        host.keepalive = heartbeat
        if rng.random() < 0.3:
            host.handshake()  # a Hello while armed disarms too
        else:
            assert isinstance(host.request(Disarm()), Ack)
        host.poll(rng.uniform(0.0, 0.15))  # anywhere in a frame, or several frames later
        _arm_from_rest(target, host)
        assert isinstance(host.request(Disarm()), Ack), f"cycle {cycle}"


@pytest.mark.link_watchdog
def test_an_arm_out_of_failsafe_starts_the_rotors_from_rest(target, host):
    rng = random.Random(0xFA11)
    for _ in range(2):
        silence_after_a_steady_stream(target, host, setpoint(target.spec, speed=rng.uniform(400.0, 800.0)))
        host.keepalive = heartbeat
        host.poll(rng.uniform(0.0, 0.05))
        _arm_from_rest(target, host)  # FAILSAFE -> ARMED by the Arm itself
        assert isinstance(host.request(Disarm()), Ack)
