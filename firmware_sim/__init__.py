"""Everything on the far side of the wire: the emulated ADK board and, for closed-loop runs, the world."""
