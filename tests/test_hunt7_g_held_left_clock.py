"""What a live phone source held before its run started is never handed to the run from a clock the phone
left (issue: an app restarted while ``hil run`` waited for its phone — SensaGram's boot clock back at 1 s
from 5000 s — had its old clock's readings, stamped *after* the new clock's and so never "older than the
newest", handed to the estimator as its first readings, as the present; the run's guard then saw the
clock go back — a ``RESTART`` and honest readings dropped as ``past``; a stray the wait anchored on,
1000 s ahead, reached the estimator as its first reading too).

At :meth:`ListeningSource.start` the readings held up to the last one of a clock the stream left (its
admission policy re-anchored on a later clock) are dropped, counted in ``held_stale`` and logged.

Real UDP sockets, real receiver and source; what is handed over then goes through the host's own admission
policy, as the run's estimator task feeds it.
"""

from __future__ import annotations

import json
import socket
import time

from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from hil.estimation.admission import PhoneGuard, Verdict
from hil.link.sources.listening import ListeningSource
from hil.link.sources.phone_udp import PhoneUdpReceiver

GYR, ACC = "android.sensor.gyroscope", "android.sensor.accelerometer"
STEP_NS = 5 * 10**6  # 200 Hz


def _event(type_: str, t_ns: int, z: float) -> bytes:
    return json.dumps({"type": type_, "timestamp": t_ns, "values": [0.0, 0.0, z]}).encode()


def _wait_messages(receiver: PhoneUdpReceiver, n: int) -> None:
    end = time.monotonic() + 10.0
    while receiver.stats.messages < n:
        assert time.monotonic() < end, receiver.stats
        time.sleep(0.001)


def _stream(sock: socket.socket, address: tuple[str, int], t0_ns: int, pairs: int) -> int:
    """``pairs`` gyroscope and accelerometer readings from ``t0_ns`` on; the datagrams sent."""
    for k in range(pairs):
        t = t0_ns + k * STEP_NS
        sock.sendto(_event(GYR, t, 0.001), address)
        sock.sendto(_event(ACC, t + 1000, 9.81), address)
    return 2 * pairs


@settings(max_examples=16, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    moved=st.sampled_from(["restart", "jump", "stray"]),
    during=st.sampled_from(["wait", "arming"]),
    before=st.integers(12, 150),
    after=st.integers(12, 120),
)
def test_readings_of_a_clock_the_phone_left_are_never_handed_to_the_run(moved, during, before, after):
    """Drawn: how the phone's clock moved (its app restarted: back from 5000 s to 1 s; stepped forward
    from 1 s to 5000 s; or the first datagram a stray 1000 s ahead of the stream), whether it moved while
    the run waited for the phone or while the board was armed after, and how many reading pairs came
    before and after. Handed to the run: only the clock the phone keeps now; every reading received is
    handed or counted in ``held_stale``; the host's policy, fed them as the run does, sees no clock move
    and drops nothing."""
    assume(moved != "stray" or during == "wait")  # a stray anchor holds the wait until the stream moves it
    old_ns, new_ns = {"restart": (5000 * 10**9, 10**9), "jump": (10**9, 5000 * 10**9)}.get(
        moved, (0, 5 * 10**9)
    )
    with (
        PhoneUdpReceiver("udp://127.0.0.1:0") as receiver,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock,
    ):
        source = ListeningSource(receiver)
        address = ("127.0.0.1", int(source.url.rsplit(":", 1)[1]))
        if moved == "stray":
            sock.sendto(_event(GYR, new_ns + 1000 * 10**9, 0.001), address)
            sent = 1
        else:
            sent = _stream(sock, address, old_ns, before)
        if during == "wait":
            sent += _stream(sock, address, new_ns, after)
        _wait_messages(receiver, sent)
        source.wait_ready(5.0, lambda: None)
        if during == "arming":
            sent += _stream(sock, address, new_ns, after)
            _wait_messages(receiver, sent)

        assert source.start(0.0) is None
        handed = []
        while batch := source.drain(0.0):
            handed += batch
        low, high = (new_ns - 10**9) / 1e9, (new_ns + 10**9) / 1e9  # the clock the phone keeps now
        assert all(low < s.t_s < high for s in handed), sorted({round(s.t_s) for s in handed})
        assert handed
        assert len(handed) + receiver.stats.held_stale == receiver.stats.samples == sent

        guard = PhoneGuard()
        verdicts = [guard.admit(s, 0.005 * (k // 64)) for k, s in enumerate(handed)]  # MAX_BATCH a tick
        assert set(verdicts) == {Verdict.ACCEPT}, guard.stats.dropped
