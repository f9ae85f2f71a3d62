"""The board's shared vocabulary: the MCU's phase and the ``Log.code`` values it sends.

Every part of the board uses these (and ``firmware_sim.avr.codegen`` writes :class:`LogCode` into the C
firmware's header), so they live apart from the :class:`~firmware_sim.board.Board` itself.
"""

from __future__ import annotations

import enum


class McuPhase(enum.Enum):
    """What the microcontroller is doing (independent of the protocol's BoardState)."""

    RESET = "reset"  # held in reset or booting: no main loop, no pulses
    RUNNING = "running"
    HUNG = "hung"  # main loop stuck: pulse timers keep their last widths, the MCU watchdog runs


class LogCode(enum.IntEnum):
    """``Log.code`` values this board sends."""

    BOOT = 1
    STATE = 2
    LINK_LOST = 3
    LINK_RESTORED = 4
    POWER = 5
    DEAD_ESC = 6
    UBEC_OVERCURRENT = 7
    HANDSHAKE = 8
    BAD_COMMAND = 9
    CALIBRATION = 10
    RX_OVERFLOW = 11
    ESC_CALIBRATION = 12
