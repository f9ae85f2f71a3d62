"""What a live phone source held before its run started is not handed to the run as the present (issue: a
phone whose accelerometer came 3 s after its gyroscope had the 3 s of gyroscope readings held while the host
waited for it — ``wait_ready`` — handed to the estimator as the run started, as if live: their delay shrank
faster than any clock runs, so the host journalled two ``phone_jump`` faults of a clock that never jumped,
dropped honest readings as ``future`` and restarted its warm-up).

At :meth:`ListeningSource.start` the readings held (during the wait, and while the board was armed) that are
stamped more than ``HELD_KEEP_S`` before the newest are dropped, counted (``held_stale``) and logged; the
rest are handed over as before, and a stray stamped far ahead cannot make the honest ones look old.

Real UDP socket, real receiver and source; the held readings then go through the host's own admission
policy with host times, as the run's estimator task feeds them.
"""

from __future__ import annotations

import json
import socket
import time

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.estimation.admission import PhoneGuard, Verdict
from hil.link.sources.listening import HELD_KEEP_S, ListeningSource
from hil.link.sources.phone_udp import PhoneUdpReceiver

GYR, ACC = "android.sensor.gyroscope", "android.sensor.accelerometer"


def _event(type_: str, t_ns: int, z: float) -> bytes:
    return json.dumps({"type": type_, "timestamp": t_ns, "values": [0.0, 0.0, z]}).encode()


def _wait_messages(receiver: PhoneUdpReceiver, n: int) -> None:
    end = time.monotonic() + 10.0
    while receiver.stats.messages < n:
        assert time.monotonic() < end, receiver.stats
        time.sleep(0.001)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    gyro_only_s=st.sampled_from([0.0, 0.1, HELD_KEEP_S, 0.9, 3.0, 8.0]),
    during_arm=st.integers(0, 40),
    stray=st.booleans(),
)
def test_readings_held_before_the_run_are_never_handed_over_stale(gyro_only_s, during_arm, stray):
    """Drawn: how long the gyroscope streamed alone before the accelerometer (at 200 Hz), how many
    readings came after the wait while the board was armed, and a stray stamped 1000 s ahead among them.
    Handed to the run: only readings within ``HELD_KEEP_S`` of the newest honest one (the stray kept for
    the run's guard); the others counted in ``held_stale``; none lost otherwise; and the host's admission
    policy, fed them as the run does, sees no clock jump and drops nothing as ``future``."""
    with (
        PhoneUdpReceiver("udp://127.0.0.1:0") as receiver,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock,
    ):
        source = ListeningSource(receiver)
        address = ("127.0.0.1", int(source.url.rsplit(":", 1)[1]))
        t_ns, sent = 5 * 10**9, 0
        for _ in range(round(gyro_only_s / 0.005)):
            sock.sendto(_event(GYR, t_ns, 0.001), address)
            t_ns, sent = t_ns + 5 * 10**6, sent + 1
        for k in range(3):
            sock.sendto(_event(GYR, t_ns, 0.001), address)
            sock.sendto(_event(ACC, t_ns + 1000, 9.81), address)
            t_ns, sent = t_ns + 5 * 10**6, sent + 2
            if stray and k == 0:
                sock.sendto(_event(GYR, t_ns + 10**12, 0.001), address)
                sent += 1
        _wait_messages(receiver, sent)
        source.wait_ready(5.0, lambda: None)
        for _ in range(during_arm):  # the board is armed meanwhile: the phone streams on
            sock.sendto(_event(GYR, t_ns, 0.001), address)
            t_ns, sent = t_ns + 5 * 10**6, sent + 1
        _wait_messages(receiver, sent)
        newest = (t_ns - 5 * 10**6 + (1000 if during_arm == 0 else 0)) / 1e9  # the newest honest stamp

        assert source.start(0.0) is None
        handed = []
        while batch := source.drain(0.0):
            handed += batch
        honest = [s.t_s for s in handed if s.t_s < 1000.0]
        assert min(honest) >= newest - HELD_KEEP_S - 1e-9, (min(honest), newest)
        assert max(honest) == newest
        assert any(s.t_s > 1000.0 for s in handed) == stray
        assert len(handed) + receiver.stats.held_stale == receiver.stats.samples == sent

        guard = PhoneGuard()
        verdicts = [guard.admit(s, 0.005 * (k // 64)) for k, s in enumerate(handed)]  # MAX_BATCH a tick
        assert Verdict.JUMP not in verdicts and Verdict.RESTART not in verdicts
        assert guard.stats.dropped["future"] == stray
        assert guard.stats.accepted == len(honest)
