"""The real firmware in the closed loop (issue 32), measured in one run: how fast simavr runs the ATmega2560
binary on its own (simulated MHz per wall second, against the real MCU's 16 MHz), the closed loop's
real-time factor through the firmware against the same lockstep run through the Python board, and a fault
campaign's runs per minute through each (the same drawn runs, on the campaign worker's path).

All three are lockstep (:class:`~hil.timing.clock.LockstepClock`): the figures are how fast the machine
goes, not a pacing; on a machine shared with other jobs they vary with its load, the ratios less.
"""

from __future__ import annotations

import time
from dataclasses import replace

from bench.common import Result
from firmware_sim.avr.harness import F_CPU
from firmware_sim.avr.stepped import FirmwareBoard
from hil.montecarlo import parse_dispersions
from hil.montecarlo.dispersions import draw
from hil.montecarlo.runner import run_chunk
from hil.runtime.loop import RunOptions
from hil.runtime.loop import run as run_loop
from hil.scenario import Scenario, load_scenario
from hil.timing.clock import LockstepClock

NAME = "firmware_loop"
SCENARIO = "cubesat-1u"
BOARDS = ("firmware", "emulator")
CAMPAIGN = """
[faults]
hang = { count = 1 }
brownout = { count = 1 }
noise = { count = 1, duration_s = { dist = "uniform", low = 0.5, high = 2.0 }, corrupt = 0.02 }
stall = { count = 1, duration_s = { dist = "uniform", low = 0.1, high = 1.2 } }
"""
"""The campaign sample: each run a hang, a brown-out, a noise burst and a stall at drawn moments (the
firmware test's, tests/test_firmware_fault_campaign.py)."""
CAMPAIGN_SEED = 32


def simulated_mhz(seconds: float) -> float:
    """The firmware alone under simavr, booted and putting out pulse frames with no host, stepped in
    power-period spans: simulated CPU cycles per wall second (MHz)."""
    clock = LockstepClock()
    with FirmwareBoard(clock=clock) as board:
        start = time.perf_counter()
        while clock.now() < seconds:
            clock.set(min(board.next_deadline(), seconds))
            board.step()
        wall = time.perf_counter() - start
    return seconds * F_CPU / 1e6 / wall


def _scenario(board: str, duration_s: float) -> Scenario:
    sc = load_scenario(SCENARIO).with_board(board)
    return sc.with_changes(slew=replace(sc.slew, duration_s=duration_s))


def realtime_factor(board: str, duration_s: float) -> float:
    """The default scenario's lockstep run (warm-up, spin-up, slew for ``duration_s``) through ``board``:
    simulated seconds per wall second of the whole run (handshake and board start included)."""
    sc = _scenario(board, duration_s)
    start = time.perf_counter()
    result = run_loop(sc, RunOptions(out_root=None))
    wall = time.perf_counter() - start
    if result.summary.get("exit") != "completed":
        raise RuntimeError(f"{board}: the run did not complete: {result.summary.get('exit')}")
    return float(result.summary["sim_s"]) / wall


def campaign_rate(board: str, runs: int, duration_s: float) -> float:
    """Runs per minute of the fault-campaign sample through ``board`` (one worker, runs one after
    another); every run must keep every invariant, or the figure would time a broken loop."""
    sc = _scenario(board, duration_s)
    drawn = [draw(parse_dispersions(CAMPAIGN, sc), CAMPAIGN_SEED, i) for i in range(runs)]
    start = time.perf_counter()
    results = run_chunk(sc, drawn, 5.0)
    wall = time.perf_counter() - start
    for r in results:
        broken = {k: v for k, v in r.checks.items() if k.startswith("inv.") and k != "inv.first" and v}
        if not r.ok or broken:
            raise RuntimeError(f"{board}: run {r.index} failed or broke an invariant: {r.error or broken}")
    return runs / wall * 60.0


def run(quick: bool) -> list[Result]:
    mhz = simulated_mhz(2.0 if quick else 10.0)
    duration = 3.0 if quick else 20.0
    factors = {board: realtime_factor(board, duration) for board in BOARDS}
    runs, run_s = (2, 4.0) if quick else (4, 8.0)
    rates = {board: campaign_rate(board, runs, run_s) for board in BOARDS}
    loop_note = f"{SCENARIO}, lockstep, warm-up + spin-up + {duration:g} s of slew, handshake included"
    campaign_note = (
        f"{runs} runs of {run_s:g} s after the slew's start, each a hang, a brown-out, noise and a stall "
        f"(seed {CAMPAIGN_SEED}), one worker, every invariant kept"
    )
    return [
        Result(
            NAME,
            "firmware under simavr, no host",
            mhz,
            "simulated MHz",
            "the real ATmega2560",
            F_CPU / 1e6,
            True,
            "stepped in power-period spans, pulse edges recorded",
        ),
        Result(
            NAME,
            "closed loop through the firmware",
            factors["firmware"],
            "x real time",
            "through the Python board",
            factors["emulator"],
            True,
            loop_note,
        ),
        Result(
            NAME,
            "fault campaign through the firmware",
            rates["firmware"],
            "runs/min",
            "through the Python board",
            rates["emulator"],
            True,
            campaign_note,
        ),
    ]
