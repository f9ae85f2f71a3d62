"""Leaving ARMED withdraws the armed rotor pulse at once, for every target (issue 25, finding 7).

The Python board once reported the armed rotor width with state DISARMED for up to a pulse frame after a
Disarm (its widths were recomputed only at the next frame); the C firmware switches in the main-loop pass
that handles the Disarm (``app.c``: ``enter_state`` → ``apply_outputs``, before the change is reported).
What both must do: from the change on, no ``Telemetry`` that is not ARMED reports a rotor above the safe
width, and from the next frame start on the pins carry the safe width. Checked over several Disarms and
Hellos at scattered moments of the pulse frame and telemetry period, and for the link-loss FAILSAFE.
Times are the board's own (heartbeat uptime, the target's pulse record); the wire carries milliseconds.

The C firmware once failed it on a link loss (found by this test): its 1 kHz tick interrupt puts the
rotor pins at the safe width first (``app_tick`` → ``pulses_hold``), and the main loop's ``apply_outputs``
updated the reported widths (``board.outputs``) only for channels whose pulse *differed* from what was on
the timer — which the interrupt had already changed — so FAILSAFE telemetry kept reporting the armed rotor
widths (pins at 1000 µs, ``pulses_us`` 1711 ...) for as long as FAILSAFE lasted. ``apply_outputs`` now
reports every channel's width whether or not the timer needed it.
"""

from __future__ import annotations

import random

import pytest

from conformance.host import heartbeat
from conformance.targets import timeline_through, uptime_origin
from conformance.test_conformance import armed_and_streaming, setpoint, silence_after_a_steady_stream
from protocol.messages import Ack, BoardState, Disarm, Heartbeat, Telemetry

MS = 0.0015  # the wire's millisecond, and the few hundred µs the firmware takes to report the change


def _rotors_safe(widths, safe: int, tol: float = 0.0) -> bool:
    return all((w or 0) <= safe + tol for w in widths[1::2])


def _check_change(target, host, start: int, new: BoardState, beat: Heartbeat | None = None) -> None:
    """What arrived since ``start`` and the pulse record around the change to ``new``: its state-change
    ``beat``, or the first Heartbeat in state ``new`` since ``start``."""
    spec = target.spec
    safe, tol = spec.rotor_safe_us, spec.pulse_tolerance_us
    got = host.received[start:]
    late = [
        m
        for m in got
        if isinstance(m, Telemetry)
        and m.state is not BoardState.ARMED
        and not _rotors_safe(m.pulses_us, safe)
    ]
    assert not late, f"{target.name}: telemetry reports an armed rotor pulse after leaving ARMED: {late[0]}"
    if beat is None:
        beat = next(m for m in got if isinstance(m, Heartbeat) and m.state == new)
    origin = uptime_origin(target.resets(), target.now())
    t_change = origin + beat.time_ms / 1000
    frames = [f for f in timeline_through(target, t_change + MS) if t_change - 0.1 <= f.t]
    assert any(not _rotors_safe(f.widths, safe, tol) for f in frames if f.t < t_change - MS)
    bad = [f for f in frames if f.t >= t_change + MS and not _rotors_safe(f.widths, safe, tol)]
    assert not bad, (
        f"{target.name}: a moving rotor pulse at {bad[0].t:.4f} s, state {new.name} at {t_change:.4f} s"
    )


def test_disarm_and_hello_withdraw_the_armed_rotor_pulse_at_once(target, host):
    spec = target.spec
    sp = setpoint(spec, speed=450.0)
    rng = random.Random(25)
    for cycle in range(8):
        armed_and_streaming(target, host, sp, seconds=0.3)
        host.poll(rng.uniform(0.0, 2.0 / spec.frame_rate_hz))  # somewhere in a frame and a telemetry period
        start = len(host.received)
        host.keepalive = heartbeat
        if cycle % 4 == 3:
            host.handshake()  # a Hello while armed disarms too
        else:
            assert isinstance(host.request(Disarm()), Ack)
        host.poll(0.1)
        _check_change(target, host, start, BoardState.DISARMED)


@pytest.mark.link_watchdog
def test_link_loss_failsafe_withdraws_the_armed_rotor_pulse_at_once(target, host):
    sp = setpoint(target.spec, speed=450.0)
    for _ in range(2):
        start = len(host.received)
        _, beat = silence_after_a_steady_stream(target, host, sp)
        host.poll(0.1)
        _check_change(target, host, start, BoardState.FAILSAFE, beat)
