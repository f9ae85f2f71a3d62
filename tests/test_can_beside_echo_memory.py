"""The segments a CAN end remembers until their loopback comes back, and what asking them costs.

Every frame in this end's own direction and node id asks "is this one of ours?" — under the lock the
writer takes too. Before, the answer was ``deque.index`` over up to 4096 remembered segments: once the
memory was full (the virtual interface never loops back; a host that has sent 700 setpoints), each such
frame cost ~20x any other (~112 µs against 5.4 µs, bench: ``python -m bench transports``' same-node row).
Now a count beside the deque answers without a scan, with the same answers: checked here against the
deque-only model, on a real virtual bus, with a memory small enough for the oldest to be forgotten."""

from __future__ import annotations

from collections import deque

import can
import hypothesis.strategies as st
import pytest
from can_support import virtual_url
from hypothesis import given, settings

import hil.link.transports.can_bus as can_bus
from hil.link.transports.can_bus import CanTransport
from protocol.can import CanId, Direction, Priority
from protocol.frame import Framer, encode_frame
from protocol.messages import ActuatorSetpoint, Heartbeat, UnitSetpoint

NODE = 5


def _channel(url: str) -> str:
    return url.removeprefix("can://virtual/").partition("?")[0]


class _CountingDeque(deque):
    """A deque that counts the elements a look-up visits (``index``, ``in``, ``count``, ``remove``,
    iteration): the work a linear search does."""

    visited = 0

    def index(self, *args):  # type: ignore[override]
        try:
            at = super().index(*args)
        except ValueError:
            type(self).visited += len(self)
            raise
        type(self).visited += at + 1
        return at

    def __contains__(self, item):  # type: ignore[override]
        type(self).visited += len(self)
        return super().__contains__(item)

    def count(self, item):  # type: ignore[override]
        type(self).visited += len(self)
        return super().count(item)

    def remove(self, item):  # type: ignore[override]
        type(self).visited += len(self)
        return super().remove(item)

    def __iter__(self):
        for item in super().__iter__():
            type(self).visited += 1
            yield item


def test_a_same_node_frame_does_not_scan_the_remembered_segments():
    """A host that has sent 4200 segments (its memory full: the virtual bus never loops back), then 2000
    frames of another host at its node id: each is counted, and none searches the remembered segments
    one by one (before: 4096 visited per frame)."""
    url = virtual_url(node=NODE)
    raw = can.Bus(interface="virtual", channel=_channel(url))
    _CountingDeque.visited = 0
    try:
        with CanTransport(url) as host:
            host._unechoed = _CountingDeque(host._unechoed, maxlen=host._unechoed.maxlen)
            setpoint = ActuatorSetpoint(units=(UnitSetpoint(0.1, 300.0),) * 4)
            for i in range(700):
                host.write(encode_frame(setpoint, i & 0xFF))
            assert len(host._unechoed) == can_bus._ECHOES
            arb = CanId(Priority.CONTROL, Direction.TO_BOARD, NODE).value
            for k in range(2000):
                raw.send(
                    can.Message(
                        arbitration_id=arb, data=(k + 1 << 40).to_bytes(8, "little"), is_extended_id=False
                    )
                )
            for _ in range(100):
                host.read(0.01)
                if host.counters()["rx_ignored"] >= 2000:
                    break
            assert host.counters()["rx_same_node"] == 2000
            assert _CountingDeque.visited <= 2000  # at most about one per frame; before: 4096 each
    finally:
        raw.shutdown()


@settings(max_examples=80, deadline=None)
@given(st.data())
def test_the_counted_memory_answers_as_the_deque_index_model_does(data):
    """Random sends, loopbacks of any segment ever sent (in or out of order, again, long forgotten) and
    other nodes' frames at this node id, on a real virtual bus, with a memory of a few segments: the host
    counts exactly the frames the deque-only model (``deque(maxlen).index``, popping up to the match)
    counts as another node's, and remembers exactly what it would."""
    echoes = data.draw(st.integers(1, 12), label="memory")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(can_bus, "_ECHOES", echoes)
        url = virtual_url(node=NODE)
        raw = can.Bus(interface="virtual", channel=_channel(url))
        model: deque[tuple[int, bytes]] = deque(maxlen=echoes)
        expected = 0
        sent: list[tuple[int, bytes]] = []
        framer = Framer()
        try:
            with CanTransport(url) as host:
                for _ in range(data.draw(st.integers(1, 30), label="steps")):
                    what = data.draw(st.sampled_from(["send", "echo", "other"]), label="what")
                    if what == "send" or not sent:
                        host.write(framer.encode(Heartbeat(time_ms=data.draw(st.integers(0, 3))))[1])
                        while (msg := raw.recv(0.0)) is not None:
                            key = (msg.arbitration_id, bytes(msg.data))
                            sent.append(key)
                            model.append(key)
                        continue
                    if what == "echo":
                        key = data.draw(st.sampled_from(sent), label="echo of")
                    else:
                        arb = CanId(Priority.LINK, Direction.TO_BOARD, NODE).value
                        key = (arb, bytes([0xC0 | data.draw(st.integers(0, 63))]) + b"\xfe" * 7)
                    raw.send(can.Message(arbitration_id=key[0], data=key[1], is_extended_id=False))
                    host.read(0.0)
                    if key in model:
                        for _ in range(model.index(key) + 1):
                            model.popleft()
                    else:
                        expected += 1
                    assert host.counters()["rx_same_node"] == expected
                    assert list(host._unechoed) == list(model)
                    assert sum(host._unechoed_count.values()) == len(model)
                    assert all(host._unechoed_count[k] == model.count(k) for k in model)
        finally:
            raw.shutdown()
