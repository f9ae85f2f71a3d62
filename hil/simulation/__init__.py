"""The simulated spacecraft's surroundings, pure math (no I/O): the simulated phone on the body
(:mod:`.phone`)."""
