"""The world on the far side of the board, for closed-loop emulation: :class:`World` (:mod:`.world`) lets the
board's pulses drive the spacecraft's motors and hands out what the phone on it senses; :mod:`.phone_faults`
is what that phone does wrong on purpose; :mod:`.lag` how far a real-time world falls behind its board's
clock, and why. The board it reads is :mod:`firmware_sim.board`."""

from .world import World, WorldStreamer, load_kernels

__all__ = ["World", "WorldStreamer", "load_kernels"]
