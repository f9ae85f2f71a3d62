"""Beside the reset-cause tests: a reset (button, watchdog, brown-out) while the board is sending a frame on
UART0 leaves the host holding that frame's start. The board's first frame after the reset is the boot
``Log`` with the reset cause; the host's deframer joined it to the cut start, so the only frame that said
why the board restarted was the one lost, at nearly every reset of a busy board (telemetry keeping the line
busy). The firmware now sends a lone delimiter first (docs/protocol.md: idle fill, "to flush a receiver
that holds garbage"): the cut start is one bad frame on its own and the boot Log arrives.

The firmware under simavr, resets at drawn moments (the seed is in every message)."""

from __future__ import annotations

import random

import pytest
from conformance.host import SerialHost

from firmware_sim.avr import AvrBoard, HarnessOptions
from firmware_sim.board.codes import LogCode
from firmware_sim.board.config import BoardConfig
from protocol.messages import Log

pytestmark = pytest.mark.firmware

# four units' telemetry at 100 Hz keeps 115200 baud busy most of the time: a reset nearly always cuts a frame
CONFIG = BoardConfig(n_units=4, telemetry_rate_hz=100.0)
RESETS = 4


def test_the_boot_log_after_a_reset_in_the_middle_of_a_frame_reaches_the_host():
    seed = random.randrange(2**32)
    rng = random.Random(seed)
    print(f"seed {seed}")  # shown with a failure: the draws to replay
    with AvrBoard(CONFIG, HarnessOptions()) as b:
        host = SerialHost(b.port, clock=b.now)
        try:
            host.handshake()
            for k in range(RESETS):
                why = f"seed {seed}, reset {k}"
                host.poll(rng.uniform(0.1, 0.4))
                bad0 = host.damage_seen()
                b.press_reset()
                boot = host.wait_type(Log, 2.0, lambda m: m.code == LogCode.BOOT)
                assert boot.text == "boot: reset cause EXTERNAL", why
                assert host.damage_seen() - bad0 <= 1, why  # the cut frame, at most, and only it
                host.handshake()
        finally:
            host.close()
        assert [r.cause.name for r in b.resets()] == ["POWER_ON"] + ["EXTERNAL"] * RESETS
        b.check()
