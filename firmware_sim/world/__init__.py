"""The world on the far side of the board, for closed-loop emulation: :class:`World` (:mod:`.world`) lets the
board's pulses drive the spacecraft's motors and hands out what the phone on it senses; :mod:`.phone_faults`
is what that phone does wrong on purpose. The board it reads is :mod:`firmware_sim.board`."""

from .world import World, WorldStreamer

__all__ = ["World", "WorldStreamer"]
