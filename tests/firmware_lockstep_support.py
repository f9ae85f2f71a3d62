"""A host on the C firmware's UART in lockstep (the firmware on simavr, stepped on a LockstepClock): it
writes frames, runs the board, and keeps what the board answered, the Logs it said and its newest
``rx_bad`` (tests/test_firmware_rx_keeps_up.py, tests/test_firmware_answers_kept.py)."""

from __future__ import annotations

import hypothesis.strategies as st

from firmware_sim.board.config import BoardConfig
from hil.timing.clock import LockstepClock
from protocol.frame import BadFrame, Deframer, encode_frame
from protocol.messages import Ack, Flags, Heartbeat, HelloReply, Log, Nack, Telemetry

RELIABLE = int(Flags.ACK_REQUESTED)

loaded_configs = st.builds(
    BoardConfig,
    n_units=st.integers(1, 6),
    frame_rate_hz=st.sampled_from([50.0, 250.0, 490.0]),
    telemetry_rate_hz=st.sampled_from([20.0, 50.0, 100.0]),
    rotor_safe_us=st.just(1000),
)
"""Boards from light to the heaviest load the tests put on the firmware's main loop and its 115200-baud
line: up to six units, 490 Hz pulse frames, 100 Hz telemetry."""


class Host:
    """A host on the firmware's UART in lockstep: writes frames, runs the board, reads what it says."""

    def __init__(self, config: BoardConfig) -> None:
        from firmware_sim.avr.stepped import FirmwareBoard

        self.clock = LockstepClock()
        self.board = FirmwareBoard(config, clock=self.clock)
        self.deframer = Deframer()
        self.seq = 0
        self.answers: dict[tuple[int, int], list[str]] = {}  # (msg_id, seq) -> its answers (Ack/Nack reason)
        self.hello_replies = 0
        self.logs: list[str] = []
        self.rx_bad = 0

    def close(self) -> None:
        self.board.close()

    def send(self, *messages, flags: int = RELIABLE) -> list[int]:
        """``messages`` in one write; returns their sequence numbers."""
        seqs, data = [], b""
        for m in messages:
            seqs.append(self.seq)
            data += encode_frame(m, self.seq, flags)
            self.seq = (self.seq + 1) & 0xFF
        self.board.feed(data)
        return seqs

    def run(self, dt: float, heartbeat_s: float | None = None) -> None:
        end = self.clock.now() + dt
        next_beat = self.clock.now()
        while self.clock.now() < end - 1e-9:
            if heartbeat_s is not None and self.clock.now() >= next_beat:
                self.send(Heartbeat(time_ms=0, state=0), flags=0)
                next_beat += heartbeat_s
            step_to = min(end, next_beat if heartbeat_s else end, self.board.next_deadline())
            self.clock.set(max(step_to, self.clock.now() + 1e-6))
            self.board.step()
            self._read()

    def _read(self) -> None:
        for e in self.deframer.feed(self.board.take_output()):
            assert not isinstance(e, BadFrame), f"the firmware sent a bad frame: {e}"
            m = e.message
            if isinstance(m, Ack | Nack):
                said = "ack" if isinstance(m, Ack) else f"nack {m.reason.name}"
                self.answers.setdefault((m.msg_id, m.seq), []).append(said)
            elif isinstance(m, HelloReply):
                self.hello_replies += 1
            elif isinstance(m, Log):
                self.logs.append(m.text)
            elif isinstance(m, Telemetry):
                self.rx_bad = m.rx_bad
