"""A CAN board that transmits by arbitration priority, as a controller with several transmit mailboxes does
(what docs/protocol.md's priority classes are for): a Heartbeat (LINK) queued while a multi-segment
Telemetry (STATUS) is still going out wins arbitration and completes first, so the Telemetry, made a few ms
before the Heartbeat, arrives after it.

Before, the session kept one last uptime for both kinds: the Telemetry's was "its uptime went back from
5556 ms to 5553 ms", a reset, 20 a second, each followed by a handshake that left the board DISARMED under
an armed host. Now a sample a little behind the newest of the other kind, its own kind in order, is a frame
overtaken on the way (``board_samples_overtaken``); a board that really restarts is still a reset.

Through a real python-can virtual bus, the project's CAN transport and segmenter, and the real client.
"""

from __future__ import annotations

import threading
import time

import can
import pytest

from hil.link.board import BoardClient, BoardResetEvent
from hil.link.board.session import OVERTAKEN_MS
from hil.link.transports.can_bus import CanTransport
from protocol.can import CanSegmenter, Direction
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import (
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    Disarm,
    Heartbeat,
    Hello,
    HelloReply,
    Telemetry,
    UnitSetpoint,
    UnitState,
)

UNITS = 4
NODE = 5
WRAP = 1 << 32  # a board's uptime is a u32 of ms: it wraps after 49.7 days


class _PriorityBoard:
    """A board on ``url`` whose every Telemetry (each 50 ms) is overtaken by a Heartbeat made ``lead_ms``
    after it (its segments sent between the Telemetry's); :meth:`restart` gives it a new boot."""

    def __init__(self, url: str, lead_ms: int, up_s: float = 5.0) -> None:
        self.far = CanTransport(url, sends=Direction.TO_HOST).open()
        self.segmenter = CanSegmenter(NODE, Direction.TO_HOST, False)
        self.framer = Framer()
        self.lead_ms = lead_ms
        self.state = BoardState.DISARMED
        self.boot_id = 0x1234ABCD
        self.t0 = time.monotonic() - up_s  # up_s up
        self.stop = threading.Event()
        self.lock = threading.Lock()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def uptime_ms(self) -> int:
        return int((time.monotonic() - self.t0) * 1000) % WRAP

    def restart(self) -> None:
        with self.lock:
            self.t0 = time.monotonic() - 0.3  # a new boot, 300 ms up by its first frame
            self.boot_id = 0x5EED0002
            self.state = BoardState.DISARMED

    def _send(self, message) -> None:  # type: ignore[no-untyped-def]
        for seg in self.segmenter.segment(self.framer.encode(message)[1]):
            self.far._bus.send(
                can.Message(arbitration_id=seg.arbitration_id, data=seg.data, is_extended_id=False)
            )

    def _serve(self) -> None:
        deframer = Deframer()
        due = time.monotonic()
        while not self.stop.is_set():
            for ev in deframer.feed(self.far.read(0.01)):
                if not isinstance(ev, Frame):
                    continue
                m = ev.message
                with self.lock:
                    if isinstance(m, Hello):
                        self.state = BoardState.DISARMED
                        reply = HelloReply(
                            schema_hash=SCHEMA_HASH,
                            state=self.state,
                            n_units=UNITS,
                            frame_rate_hz=50,
                            boot_id=self.boot_id,
                            model="PRIO",
                        )
                        self._send(reply)
                    elif m.RELIABLE:
                        if isinstance(m, Arm):
                            self.state = BoardState.ARMED
                        elif isinstance(m, Disarm):
                            self.state = BoardState.DISARMED
                        self._send(Ack(msg_id=ev.msg_id, seq=ev.seq))
            if time.monotonic() >= due:
                due += 0.05
                with self.lock:
                    t = self.uptime_ms()
                    tel = Telemetry(
                        time_ms=t,
                        state=self.state,
                        units=tuple(UnitState() for _ in range(UNITS)),
                        pulses_us=(1000,) * (2 * UNITS),
                        rx_frames=10,
                    )
                    tel_segments = self.segmenter.segment(self.framer.encode(tel)[1])
                    beat = Heartbeat(
                        time_ms=(t + self.lead_ms) % WRAP, state=self.state, boot_id=self.boot_id
                    )
                    beat_segments = self.segmenter.segment(self.framer.encode(beat)[1])
                    assert len(tel_segments) > 3
                    for seg in [*tel_segments[:3], *beat_segments, *tel_segments[3:]]:
                        msg = can.Message(
                            arbitration_id=seg.arbitration_id, data=seg.data, is_extended_id=False
                        )
                        self.far._bus.send(msg)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.far.close()


@pytest.mark.parametrize(
    ("lead_ms", "up_s"),
    [(1, 5.0), (3, 5.0), (OVERTAKEN_MS, 5.0), (3, WRAP / 1000.0 - 0.8)],  # the last: its uptime wraps
)
def test_telemetry_overtaken_by_a_heartbeat_is_no_reset_and_a_real_restart_still_is(lead_ms, up_s):
    """Also across the uptime's wrap (a board up 49.7 days): a Telemetry made just before it, overtaken by a
    Heartbeat made just after it, went back by a few ms, not on by 49 days — it was refused as a leap."""
    url = f"can://virtual/priority-order-{lead_ms}-{up_s:.0f}?node={NODE}"
    board = _PriorityBoard(url, lead_ms, up_s)
    client = BoardClient(url)
    try:
        client.connect(timeout=5.0)
        client.start()
        client.arm()
        time.sleep(1.5)  # 30 overtaken telemetries
        events = client.drain_events()
        assert not [e for e in events if isinstance(e, BoardResetEvent)]
        stats = client.stats()
        assert stats.as_dict()["counters.resets"] == 0 and stats.as_dict()["counters.handshakes"] == 1
        assert stats.as_dict()["counters.board_samples_overtaken"] >= 5  # ~30, fewer on a busy machine
        assert stats.as_dict()["counters.board_leaps"] == 0
        assert client.state is BoardState.ARMED
        client.send_setpoint(ActuatorSetpoint(units=(UnitSetpoint(0.0, 100.0),) * UNITS))  # still armed
        board.restart()
        deadline = time.monotonic() + 5.0
        resets: list[BoardResetEvent] = []
        while not resets and time.monotonic() < deadline:
            time.sleep(0.05)
            resets = [e for e in client.drain_events() if isinstance(e, BoardResetEvent)]
        assert len(resets) == 1, "a board that restarted is a reset"
    finally:
        client.close()
        board.close()
