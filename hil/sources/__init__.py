"""Where the host's sensor samples come from: a recorded log, a live phone stream, the simulated phone."""
