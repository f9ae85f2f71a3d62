"""VSCMG steering (the weighted pseudo-inverse, :mod:`hil.control.steering`) compiled, against its numpy
reference (:mod:`hil.control.steering_reference`) in the same run: µs per call of ``solve`` as the host
makes it (one row per control tick), and per row in a batch of 64, with and without null motion."""

from __future__ import annotations

from functools import partial

import numpy as np

from bench.common import Result, rate
from hil.control import steering_reference
from hil.control.steering import SteeringParams, VscmgSteering
from hil.vscmg import cubesat_1u

NAME = "steering"


def run(quick: bool) -> list[Result]:
    params = cubesat_1u()
    rng = np.random.default_rng(0)
    results = []
    min_time = 0.1 if quick else 0.5
    for null_gain in (0.0, 1.0):
        steer = VscmgSteering(params, SteeringParams(null_gain=null_gain))
        for rows in (1, 64):
            gam = rng.uniform(-np.pi, np.pi, (rows, params.n_units))
            w = np.full((rows, params.n_units), params.nominal_rotor_speed)
            torque = rng.normal(size=(rows, 3)) * 1e-4
            ours = rate(partial(steer.solve, torque, gam, w, 0.02), min_time)
            ref = rate(partial(steering_reference.solve, steer, torque, gam, w, 0.02), min_time)
            label = f"solve, {rows} row{'s' if rows > 1 else ''}{', null motion' if null_gain else ''}"
            us, ref_us = 1e6 / ours / rows, 1e6 / ref / rows
            note = "compiled kernel vs the numpy law it replaced"
            results.append(Result(NAME, label, us, "us/row", "numpy reference", ref_us, False, note))
    return results
