"""Calibration conversions per second: our scalar maps (what the board calls per setpoint) next to scipy
doing the same job on the same table in the same run — ``PchipInterpolator`` called per sample for the
forward map, and ``scipy.optimize.brentq`` on it for the inverse (the generic way to invert a monotone
interpolant). Plus fitting time for a bench CSV (no peer), the binary codec's round trips per second, and
how fast a bench sweep runs against the emulator in simulated time (``emu://``, four bench units' rotors
swept together through the full protocol) next to the real time the same sweep takes on a bench.
"""

from __future__ import annotations

import random
import time

from scipy.interpolate import PchipInterpolator
from scipy.optimize import brentq

from bench.common import Result, rate
from hil.calibration.bench import read_bench_csv
from hil.calibration.fit import fit_bench
from hil.scenario.paths import FIXTURES
from protocol.calibration import UnitCalibration, default_unit_calibration
from protocol.messages import GimbalMode

NAME = "calibration"


def run(quick: bool) -> list[Result]:
    min_time = 0.1 if quick else 0.5
    cal = default_unit_calibration()
    rng = random.Random(1)
    pulses = [rng.uniform(1000.0, 2000.0) for _ in range(256)]
    rates = [rng.uniform(-1.9, 1.9) for _ in range(256)]
    it = iter(range(1 << 62))

    upper = cal.gimbal_rate.upper
    peer = PchipInterpolator(upper.x, upper.y)
    x0, x1 = upper.x[0], upper.x[-1]
    up_rates = [r for r in (abs(v) for v in rates) if 0.01 < r < upper.y[-1]]

    xs = [x0 + (p - 1000.0) * (x1 - x0) / 1000.0 for p in pulses]  # inside the upper table

    def ours_forward() -> None:
        upper.evaluate(xs[next(it) & 255])

    def peer_forward() -> None:
        float(peer(xs[next(it) & 255]))

    def gimbal_setpoint() -> None:
        cal.gimbal_pulse_us(rates[next(it) & 255], GimbalMode.RATE)

    def ours_inverse() -> None:
        upper.solve(up_rates[next(it) % len(up_rates)])

    def peer_inverse() -> None:
        r = up_rates[next(it) % len(up_rates)]
        brentq(lambda x: float(peer(x)) - r, x0, x1, xtol=1e-4)

    def rotor_setpoint() -> None:
        cal.rotor_pulse_us(rates[next(it) & 255] * 150.0 + 300.0, 11.1)

    data = cal.to_bytes()

    def codec() -> None:
        UnitCalibration.from_bytes(data)

    csv = read_bench_csv(FIXTURES / "calibration" / "bench" / "unit0_rotor.csv")
    t0 = time.perf_counter()
    fits = 1 if quick else 3
    for _ in range(fits):
        fit_bench(csv)
    fit_s = (time.perf_counter() - t0) / fits

    sim_s, wall_s, steps = _lockstep_sweep(quick)

    return [
        Result(
            NAME,
            "table evaluate (pulse → rate)",
            rate(ours_forward, min_time),
            "conv/s",
            "scipy Pchip call",
            rate(peer_forward, min_time),
        ),
        Result(
            NAME,
            "table inverse (rate → pulse)",
            rate(ours_inverse, min_time),
            "conv/s",
            "scipy brentq on Pchip",
            rate(peer_inverse, min_time),
        ),
        Result(
            NAME,
            "gimbal rate setpoint → pulse",
            rate(gimbal_setpoint, min_time),
            "conv/s",
            note="either side of the dead zone, incl. the hold pulse",
        ),
        Result(
            NAME,
            "rotor setpoint → pulse",
            rate(rotor_setpoint, min_time),
            "conv/s",
            note="speed and battery V → pulse, incl. the throttle map",
        ),
        Result(
            NAME, "binary set parse + validate", rate(codec, min_time), "sets/s", note=f"{len(data)} bytes"
        ),
        Result(
            NAME,
            "fit a rotor bench CSV",
            fit_s * 1e3,
            "ms",
            higher_is_better=False,
            note=f"{len(csv)} rows, 9 knots, least squares",
        ),
        Result(
            NAME,
            "rotor sweep of 4 bench units, emu:// lockstep",
            sim_s / wall_s,
            "x real time",
            "the same sweep on a bench (real time)",
            1.0,
            note=f"{steps} steps up and down, {sim_s:.0f} s of board time in {wall_s:.1f} s",
        ),
    ]


def _lockstep_sweep(quick: bool) -> tuple[float, float, int]:
    """(board seconds, wall seconds, steps) of a rotor sweep of 4 bench units through emu:// in lockstep."""
    from hil.calibration.bench import BenchKind
    from hil.calibration.benchlink import BenchLink
    from hil.calibration.sweep import SweepPlan, run_sweep
    from hil.link.board import BoardClient
    from hil.timing.clock import LockstepClock

    plan = SweepPlan(BenchKind.ROTOR, step_us=200 if quick else 40)
    clock = LockstepClock()
    with BoardClient("emu://?units=4&unit_spread=3", clock=clock) as client:
        t0, w0 = clock.now(), time.perf_counter()
        results = run_sweep(BenchLink(client), [0, 1, 2, 3], plan)
        return clock.now() - t0, time.perf_counter() - w0, len(results[0].rows)
