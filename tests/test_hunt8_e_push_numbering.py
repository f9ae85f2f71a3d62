"""Sensor Logger pushes beside the tested path: numbered batches that arrive out of order, and two clients
without ids behind one address. A real :class:`PhonePushServer`, real HTTP over loopback.

Before:

* a batch overtaken by the next (an HTTP retry arriving late: ids 1, 2, 4, 3, 5) counted two batches
  lost and a numbering restart, none lost (``message_gaps`` 2, ``message_restarts`` 1);
* two clients pushing without ``deviceId`` and ``sessionId`` from one address (two phones behind one NAT,
  two scripts on one laptop) were one sender, the peer's address: their readings were interleaved into one
  stream, as if from one phone — nothing dropped, nothing counted, nothing logged.
"""

from __future__ import annotations

import http.client
import json

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind
from hil.link.sources.phone_push import (
    LATE_WINDOW,
    MAX_NUMBERINGS,
    MessageNumbering,
    PeerNumberings,
    PhonePushServer,
)
from hil.link.sources.senders import MAX_SENDERS

T0_NS = 1_698_501_144_401_773_000
BATCH_NS = 20_000_000  # the app's 20 ms batch period


def _body(message_id: int, t_ns: int, z: float, ids: bool) -> bytes:
    reading = {"name": "gyroscope", "time": t_ns, "values": {"x": 0.0, "y": 0.0, "z": z}}
    doc: dict[str, object] = {"messageId": message_id, "payload": [reading]}
    if ids:
        doc.update(sessionId="session-a", deviceId="phone-a")
    return json.dumps(doc).encode()


def _post(conn: http.client.HTTPConnection, body: bytes) -> None:
    conn.request("POST", "/", body, {"Content-Type": "application/json"})
    answer = conn.getresponse()
    answer.read()
    assert answer.status == 200


# --------------------------------------------------------------------------- out of order
@st.composite
def arrivals(draw: st.DrawFn) -> tuple[list[int], int]:
    """A phone's ids 0..n-1 as they reach the host: some never (``lost``), some late by a few places (a
    retry on a second connection), some twice (a retry of one received); the first heard is the first
    sent (an id below the first one heard is a numbering started again). Returns (order, lost)."""
    n = draw(st.integers(3, 60))
    lost = draw(st.sets(st.integers(1, n - 2), max_size=n // 3))  # the first and the last arrive
    order = [i for i in range(n) if i not in lost]
    for _ in range(draw(st.integers(0, 6)) if len(order) > 2 else 0):  # one later by up to 8 places
        i = draw(st.integers(1, len(order) - 2))
        j = draw(st.integers(i + 1, min(i + 8, len(order) - 1)))
        order.insert(j, order.pop(i))
    if order[-1] != n - 1:  # the newest last: what is still missing then is what was lost
        order.remove(n - 1)
        order.append(n - 1)
    for _ in range(draw(st.integers(0, 4))):  # a retry of one received, somewhere after it
        i = draw(st.integers(0, len(order) - 1))
        order.insert(draw(st.integers(i + 1, len(order))), order[i])
    return order, len(lost)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(arrived=arrivals())
def test_batches_arriving_late_or_twice_are_not_counted_lost(arrived):
    order, lost = arrived
    with PhonePushServer("http://127.0.0.1:0/") as server:
        conn = http.client.HTTPConnection("127.0.0.1", server._httpd.server_port, timeout=10)
        try:
            for message_id in order:
                _post(conn, _body(message_id, T0_NS + message_id * BATCH_NS, 0.01, ids=True))
        finally:
            conn.close()
        stats = server.stats
        assert (stats.message_gaps, stats.message_restarts) == (lost, 0), order
        assert stats.messages == len(order)


@settings(max_examples=300, deadline=None)
@given(
    ids=st.lists(
        st.one_of(st.integers(-(10**6), 10**6), st.integers(-(10**400), 10**400)), min_size=1, max_size=80
    )
)
def test_a_numbering_counts_no_more_lost_than_the_ids_skipped_and_stays_small(ids):
    """Whatever the ids (far jumps, back, repeated, 400 digits): every count is bounded by what a phone
    could have sent, and what is remembered by the window."""
    numbering = MessageNumbering()
    lost = restarts = 0
    for message_id in ids:
        d_lost, d_restarts = numbering.hear(message_id)
        lost, restarts = lost + d_lost, restarts + d_restarts
        assert lost >= 0 and restarts >= 0
        assert len(numbering._missing) <= LATE_WINDOW
    assert restarts <= len(ids) - 1
    assert lost <= (len(ids) - 1) * 100_000


# --------------------------------------------------------------------------- two clients, one address
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    start_b=st.one_of(st.integers(LATE_WINDOW + 2, 10**6), st.integers(-(10**6), -(LATE_WINDOW + 2))),
    batches=st.integers(4, 30),
    b_first=st.booleans(),
)
def test_two_clients_without_ids_behind_one_address_are_never_merged(start_b, batches, b_first):
    """Two clients push from 127.0.0.1 without ``deviceId`` or ``sessionId``, each on its own keep-alive
    connection, taking turns: client A numbers from 0, its gyroscope reads +0.01 rad/s; client B numbers
    from ``start_b``, its gyroscope reads -0.5 rad/s. Only the first heard is delivered; the other's
    batches are dropped and counted as another phone's."""
    with PhonePushServer("http://127.0.0.1:0/") as server:
        port = server._httpd.server_port
        a = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        b = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        try:
            for k in range(batches):
                t = T0_NS + k * BATCH_NS
                pushes = [
                    (a, _body(k, t, 0.01, ids=False)),
                    (b, _body(start_b + k, t + 1000, -0.5, ids=False)),
                ]
                for conn, body in reversed(pushes) if b_first else pushes:
                    _post(conn, body)
        finally:
            a.close()
            b.close()
        got = server.drain()
        rates = {s.xyz[2] for s in got if s.kind is SensorKind.GYR}
        assert rates == ({-0.5} if b_first else {0.01}), rates  # one phone's readings, never both
        stats = server.stats
        assert stats.other_phones == 1 and stats.other_phone_messages == batches, stats
        assert (stats.message_gaps, stats.message_restarts) == (0, 0)


def test_one_client_without_ids_retrying_late_stays_one_sender():
    """A client without ids whose batches arrive out of order and twice (retries) is one sender."""
    order = [0, 1, 3, 2, 4, 4, 5, 7, 6, 8]
    with PhonePushServer("http://127.0.0.1:0/") as server:
        conn = http.client.HTTPConnection("127.0.0.1", server._httpd.server_port, timeout=10)
        try:
            for message_id in order:
                _post(conn, _body(message_id, T0_NS + message_id * BATCH_NS, 0.01, ids=False))
        finally:
            conn.close()
        stats = server.stats
        assert stats.other_phones == 0 and stats.phone_switches == 0, stats
        assert len(server.drain()) == len(order)
        assert (stats.message_gaps, stats.message_restarts) == (0, 0)


@settings(max_examples=100, deadline=None)
@given(heard=st.lists(st.tuples(st.integers(0, 400), st.integers(-(10**9), 10**9)), min_size=1, max_size=600))
def test_numberings_behind_addresses_stay_bounded_whatever_a_peer_sprays(heard):
    """Hundreds of addresses and ids (a peer spraying): what is remembered stays within its bounds, and an
    id is the same numbering as the id before it of its address when it follows it."""
    numberings = PeerNumberings()
    for peer, message_id in heard:
        number = numberings.which(f"10.0.{peer // 256}.{peer % 256}", message_id)
        assert numberings.which(f"10.0.{peer // 256}.{peer % 256}", message_id + 1) == number
    assert len(numberings._peers) <= MAX_SENDERS
    assert all(len(known) <= MAX_NUMBERINGS for known in numberings._peers.values())
