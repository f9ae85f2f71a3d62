"""A real-time world starts level with its board's clock, and says what lags and why when it falls behind.

Issue 31's second reproduction: ``firmware-sim --world cubesat-1u`` warned within its first second that
"the world runs 395 ms behind the board's clock: this machine cannot step the plant in real time" on an
idle machine — the board's clock started before the world's compiled kernels were loaded (from numba's
cache) on its first pass. The test checks the order itself, not a wall-clock figure: every wall clock
firmware-sim makes finds the world's kernels loaded already."""

from __future__ import annotations

import subprocess
import sys

import pytest

from firmware_sim.world.lag import LAG_WARNING_S, WARNED_EPISODES, LagMonitor
from hil import jit

_ORDER = """
import sys
import hil.timing.clock as clocks
from firmware_sim import cli
from firmware_sim.world.models import kernels, phone

loaded_at_start = []

class Recording(clocks.WallClock):
    def __init__(self):
        loaded_at_start.append(kernels.advance.loaded and phone._sample_path.loaded)
        super().__init__()

clocks.WallClock = Recording
status = cli.main(["--world", "cubesat-1u", "--duration", "0.3", "--phone", sys.argv[1]])
print(status, loaded_at_start)
"""


@pytest.mark.skipif(not jit.COMPILED, reason="NUMBA_DISABLE_JIT=1: no kernels to load")
def test_the_worlds_kernels_are_loaded_before_the_boards_clock_starts(phone_port):
    done = subprocess.run(
        [sys.executable, "-c", _ORDER, f"udp://127.0.0.1:{phone_port}"],
        capture_output=True,
        text=True,
        timeout=300,  # a fresh cache compiles the kernels
    )
    assert done.returncode == 0, done.stderr
    status, loaded = done.stdout.strip().splitlines()[-1].split(" ", 1)
    assert status == "0" and loaded.startswith("[True") and "False" not in loaded, done.stdout
    assert "started " in done.stderr and "lag episode(s)" in done.stderr, done.stderr


def test_start_up_lag_is_kept_apart_and_episodes_counted_after_it():
    m = LagMonitor()
    assert m.observe(0.4, 0.4, 0.39) is None  # start-up: behind, not an episode
    assert m.observe(0.2, 0.01, 0.01) is None
    assert m.observe(0.003, 0.005, 0.001) is None  # caught up: start-up is over
    assert (m.stats.startup_lag_s, m.stats.started, m.stats.episodes) == (0.4, True, 0)
    assert m.observe(0.05, 0.005, 0.001) is None
    # kept waiting: 300 ms of wall time, 10 ms of it stepping
    warning = m.observe(0.3, 0.3, 0.01)
    assert warning is not None and "300 ms behind" in warning and "plant and the phone" in warning
    assert "kept waiting" in warning and "3%" in warning
    assert m.observe(0.2, 0.1, 0.01) is None  # the same episode
    assert m.observe(LAG_WARNING_S * 0.6, 0.1, 0.01) is None  # not yet under half the threshold
    assert m.observe(0.01, 0.1, 0.01) is None  # over
    warning = m.observe(0.15, 0.2, 0.19)  # stepping all along: the plant is too slow
    assert warning is not None and "slower than real time" in warning and "95%" in warning
    assert (m.stats.episodes, m.stats.max_lag_s) == (2, 0.3)


def test_only_the_first_episodes_are_warned_about_and_all_are_counted():
    m = LagMonitor()
    m.observe(0.0, 0.005, 0.001)
    warnings = []
    for _ in range(WARNED_EPISODES + 3):
        warnings.append(m.observe(0.5, 0.5, 0.1))
        m.observe(0.0, 0.005, 0.001)
    assert all(w is not None for w in warnings[:WARNED_EPISODES]) and "not reported" in warnings[-4]
    assert warnings[WARNED_EPISODES:] == [None] * 3 and m.stats.episodes == WARNED_EPISODES + 3
