"""The VSCMG plant (firmware_sim.world.models) side by side with Basilisk's ``VSCMGStateEffector`` (balanced
model) on the same scenario in one run: plant steps per second and simulated seconds per wall second (4 units,
1 ms step, single run), our batch path's aggregate rate, the momentum and energy drift of both, and how
closely the two trajectories agree (Basilisk's ``speedOutMsg`` carries the gimbal angles at the start of the
step it is stamped with, so its gimbal angles are compared with ours one step earlier). (The closed loop's
figures are bench_runtime's: every closed-loop run goes through the runtime.)

The compiled plant (:class:`firmware_sim.world.models.CompiledPlant`, what the emulator's world steps) runs
the same scenarios in the same process: its steps per second inside one compiled call (the world's batches)
and with one Python call per step, against Basilisk and against the numpy :class:`Plant` at B = 1, and how far
its final state lies from the numpy plant's (rounding only). Also the emulator's whole world (plant, drives,
phone, board; ``firmware_sim.world.World``) in CPU seconds per simulated second on the compiled plant and on
the numpy references, and what compiling costs: a first run on an empty numba cache (a fresh install) against
one on a warm cache, each in a fresh process.

The shared scenario is what Basilisk's balanced model describes: a 1U bus with the 54.74° pyramid of four
units, each with diagonal gimbal and axisymmetric rotor inertias and no rotor offset or unit mass (the
balanced model ignores both); rotors at 380–420 rad/s, gimbals moving. "Free": no motor torques (energy
and momentum must both hold). "Driven": constant gimbal and rotor motor torques (momentum must hold; the
trajectories are compared).

Basilisk (PyPI ``bsk``, extra ``basilisk``) is optional: without it the peer columns stay empty.
"""

from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from bench.common import Result
from firmware_sim.world.models import CompiledPlant, Plant
from hil import so3
from hil.vscmg import UnitParams, cubesat_1u, pyramid

NAME = "dynamics"
STEP = 1e-3
OMEGA0 = np.array([0.02, -0.03, 0.015])
GIMBAL0 = np.array([0.2, -0.1, 0.3, -0.25])
GIMBAL_RATE0 = np.array([0.1, -0.05, 0.08, 0.02])
ROTOR0 = np.array([400.0, 380.0, 420.0, 410.0])
GIMBAL_TORQUE = np.array([2e-7, -1e-7, 1.5e-7, -2e-7])  # N m: gimbals reach ~0.3-0.5 rad/s in 20 s
ROTOR_TORQUE = np.array([5e-5, -2.5e-5, 4e-5, -5e-5])  # N m: rotors change by up to 100 rad/s


def balanced_params():
    """The 1U preset reduced to what Basilisk's balanced model represents."""
    unit = UnitParams(
        gimbal_axis=(0, 0, 1),
        spin_axis=(1, 0, 0),
        gimbal_inertia=(1.5e-6, 1.8e-6, 2.0e-6),
        gimbal_mass_kg=0.0,
        rotor_inertia=(1.0e-5, 5.5e-6, 5.5e-6),
        rotor_mass_kg=0.0,
        rotor_offset_m=0.0,
    )
    return dataclasses.replace(
        cubesat_1u(), bus_inertia=(2.0e-3, 2.1e-3, 2.2e-3), units=pyramid(4, template=unit)
    )


def _ours(duration: float, driven: bool) -> dict:
    params = balanced_params()
    plant = Plant(params)
    s = plant.state(omega=OMEGA0, gimbal_angle=GIMBAL0, gimbal_rate=GIMBAL_RATE0, rotor_rate=ROTOR0)
    torques = (GIMBAL_TORQUE, ROTOR_TORQUE) if driven else None
    pi0, e0 = plant.angular_momentum(s)[0], plant.kinetic_energy(s)[0]
    samples = [(s.t, s.R[0].copy(), s.omega[0].copy(), s.gimbal_angle[0].copy())]
    n = int(round(duration / STEP))
    start = time.perf_counter()
    for k in range(n):
        before = s.gimbal_angle
        s = plant.step(s, STEP, torques)
        if (k + 1) % 100 == 0:
            # gimbal angle one step back: Basilisk's speedOutMsg is written before its state update
            samples.append((s.t, s.R[0].copy(), s.omega[0].copy(), before[0].copy()))
    wall = time.perf_counter() - start
    return {
        "steps_per_s": n / wall,
        "momentum_drift": float(np.linalg.norm(plant.angular_momentum(s)[0] - pi0) / np.linalg.norm(pi0)),
        "energy_drift": float(abs(plant.kinetic_energy(s)[0] - e0) / e0),
        "samples": samples,
        "final": s,
    }


def _ours_compiled(duration: float, driven: bool, per_call: bool) -> dict:
    """The same run on the compiled plant: one call for every step (``per_call``: one Python call each, the
    torques converted to the plant's :class:`~firmware_sim.world.models.Drive` once, as the world holds its
    drives)."""
    plant = Plant(balanced_params())
    c = CompiledPlant(plant)
    state = c.pack(
        plant.state(omega=OMEGA0, gimbal_angle=GIMBAL0, gimbal_rate=GIMBAL_RATE0, rotor_rate=ROTOR0)
    )
    torques = c.drive((GIMBAL_TORQUE, ROTOR_TORQUE) if driven else None)
    c.advance(state.copy(), STEP, 1, torques)  # compiled (or loaded from the cache) before the clock runs
    n = int(round(duration / STEP))
    start = time.perf_counter()
    if per_call:
        for _ in range(n):
            c.advance(state, STEP, 1, torques)
    else:
        c.advance(state, STEP, n, torques)
    wall = time.perf_counter() - start
    return {"steps_per_s": n / wall, "final": c.unpack(state)}


def _difference(a, b) -> float:
    """Largest relative difference between two plant states, field by field."""
    fields = ("R", "momentum", "gimbal_angle", "rotor_angle", "gimbal_momentum", "rotor_momentum", "omega",
              "gimbal_rate", "rotor_rate")  # fmt: skip
    return max(
        float(np.max(np.abs(getattr(a, f) - getattr(b, f))) / np.max(np.abs(getattr(b, f)))) for f in fields
    )


def _world_cost(duration: float, compiled: bool, chunk: float = 0.005) -> tuple[float, int]:
    """CPU seconds per simulated second of the emulator's world (plant, drives, phone, board) next to an
    idle board in lockstep, advanced every ``chunk`` s, on the compiled plant or the numpy references; and
    the batches it took."""
    from firmware_sim.cli import build_parser, make_board
    from firmware_sim.world import World
    from hil.scenario import load_scenario
    from hil.timing.clock import LockstepClock

    scenario = load_scenario("cubesat-1u")
    clock = LockstepClock()
    world = World(scenario, make_board(build_parser().parse_args(["--units", "4"]), clock), compiled=compiled)
    clock.advance(chunk)
    world.advance_to(clock.now())  # compiled before the clock runs
    cpu = time.process_time()
    batches = world.batches
    for _ in range(int(round(duration / chunk))):
        clock.advance(chunk)
        world.advance_to(clock.now())
    return (time.process_time() - cpu) / duration, world.batches - batches


_FIRST_RUN = """
import time
t0 = time.perf_counter()
import numpy as np
from hil.vscmg import cubesat_1u
from firmware_sim.world.models import BodyPhone, CompiledPlant, Plant, ServoModel
t1 = time.perf_counter()
plant = Plant(cubesat_1u())
c = CompiledPlant(plant)
s = c.pack(plant.state())
path = np.zeros((3, 13))
c.advance(s, 1e-3, 2, ServoModel(plant.params), path)
BodyPhone().sample_path(path)
t2 = time.perf_counter()
print(t1 - t0, t2 - t1)
"""


def _first_run(cache_dir: str) -> tuple[float, float]:
    """(import s, first plant step and phone sample s) in a fresh process with numba's cache in
    ``cache_dir``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    out = subprocess.run(
        [sys.executable, "-c", _FIRST_RUN], env=env, capture_output=True, text=True, check=True, timeout=600
    )
    imp, first = (float(x) for x in out.stdout.split())
    return imp, first


def _compile_cost() -> list[Result]:
    """A first run on an empty numba cache (what a fresh install pays once) against a warm one."""
    with tempfile.TemporaryDirectory() as cache:
        cold_import, cold = _first_run(cache)
        warm_import, warm = _first_run(cache)
    return [
        Result(
            NAME,
            "compile on first use, empty cache (plant + drives + phone kernels)",
            cold,
            "s",
            "warm cache (loaded from disk)",
            warm,
            higher_is_better=False,
            note=f"imports (numpy, numba, hil...): {cold_import:.2f} s cold, {warm_import:.2f} s warm",
        )
    ]


def _ours_batch(duration: float, batch: int) -> float:
    """Aggregate plant steps per second of ``batch`` runs stepped together."""
    plant = Plant(balanced_params())
    rng = np.random.default_rng(1)
    s = plant.state(omega=OMEGA0 + rng.normal(0, 0.01, (batch, 3)), gimbal_angle=GIMBAL0, rotor_rate=ROTOR0)
    n = int(round(duration / STEP))
    start = time.perf_counter()
    plant.run(s, STEP, n, (GIMBAL_TORQUE, ROTOR_TORQUE))
    return batch * n / (time.perf_counter() - start)


def _basilisk(duration: float, driven: bool) -> dict | None:
    try:
        from Basilisk.architecture import messaging
        from Basilisk.simulation import spacecraft, vscmgStateEffector
        from Basilisk.utilities import RigidBodyKinematics, SimulationBaseClass, macros
    except ImportError:
        return None
    params = balanced_params()
    sim = SimulationBaseClass.SimBaseClass()
    proc = sim.CreateNewProcess("dyn")
    proc.addTask(sim.CreateNewTask("task", macros.sec2nano(STEP)))
    sc = spacecraft.Spacecraft()
    sc.ModelTag = "cubesat"
    sc.hub.mHub = params.bus_mass_kg
    sc.hub.IHubPntBc_B = np.diag(params.bus_inertia).tolist()
    sc.hub.omega_BN_BInit = [[w] for w in OMEGA0]
    sc.hub.sigma_BNInit = [[0.0], [0.0], [0.0]]
    eff = vscmgStateEffector.VSCMGStateEffector()
    eff.ModelTag = "vscmgs"
    for i, u in enumerate(params.units):
        c = messaging.VSCMGConfigMsgPayload()
        c.VSCMGModel = vscmgStateEffector.vscmgBalancedWheels
        g, s0 = np.array(u.gimbal_axis), np.array(u.spin_axis)
        c.gsHat0_B = [[x] for x in s0]
        c.gtHat0_B = [[x] for x in np.cross(g, s0)]
        c.ggHat_B = [[x] for x in g]
        c.rGB_B = [[0.0], [0.0], [0.0]]
        c.IG1, c.IG2, c.IG3 = u.gimbal_inertia
        c.IW1, c.IW2, c.IW3 = u.rotor_inertia
        c.Omega, c.gamma, c.gammaDot = float(ROTOR0[i]), float(GIMBAL0[i]), float(GIMBAL_RATE0[i])
        c.Omega_max, c.gammaDot_max, c.u_s_max, c.u_g_max = -1.0, -1.0, -1.0, -1.0
        c.massW, c.massG = 0.0, 0.0
        eff.AddVSCMG(c)
    sc.addStateEffector(eff)
    cmd = messaging.VSCMGArrayTorqueMsgPayload()
    cmd.wheelTorque = (ROTOR_TORQUE if driven else np.zeros(4)).tolist()
    cmd.gimbalTorque = (GIMBAL_TORQUE if driven else np.zeros(4)).tolist()
    cmd_msg = messaging.VSCMGArrayTorqueMsg().write(cmd)
    eff.cmdsInMsg.subscribeTo(cmd_msg)
    sim.AddModelToTask("task", eff)
    sim.AddModelToTask("task", sc)
    rec = sc.scStateOutMsg.recorder(macros.sec2nano(0.1))
    speeds = eff.speedOutMsg.recorder(macros.sec2nano(0.1))
    log = sc.logger(["totRotAngMomPntC_N", "totRotEnergy"], macros.sec2nano(0.1))
    for m in (rec, speeds, log):
        sim.AddModelToTask("task", m)
    sim.InitializeSimulation()
    sim.ConfigureStopTime(macros.sec2nano(duration))
    start = time.perf_counter()
    sim.ExecuteSimulation()
    wall = time.perf_counter() - start
    h = np.array(log.totRotAngMomPntC_N)
    e = np.array(log.totRotEnergy)
    samples = []
    for k in range(len(rec.times())):
        R = np.array(RigidBodyKinematics.MRP2C(rec.sigma_BN[k])).T
        samples.append(
            (rec.times()[k] * 1e-9, R, np.array(rec.omega_BN_B[k]), np.array(speeds.gimbalAngles[k][:4]))
        )
    return {
        "steps_per_s": duration / STEP / wall,
        "momentum_drift": float(np.linalg.norm(h[-1] - h[1]) / np.linalg.norm(h[1])),
        "energy_drift": float(abs(e[-1] - e[1]) / e[1]),
        "samples": samples,
    }


def _agreement(a: list, b: list) -> tuple[float, float, float]:
    """Largest attitude (deg), body-rate (rad/s) and gimbal-angle (rad) differences at common times."""
    tb = {round(x[0], 6): x for x in b}
    att = rate = gim = 0.0
    for t, R, w, g in a:
        other = tb.get(round(t, 6))
        if other is None:
            continue
        att = max(att, math.degrees(so3.angle_between(R, other[1])))
        rate = max(rate, float(np.max(np.abs(w - other[2]))))
        gim = max(gim, float(np.max(np.abs(g - other[3]))))
    return att, rate, gim


def run(quick: bool) -> list[Result]:
    duration = 2.0 if quick else 20.0
    results: list[Result] = []
    for driven in (False, True):
        tag = "driven" if driven else "free"
        ours = _ours(duration, driven)
        peer = _basilisk(duration, driven)
        pv = None if peer is None else peer["steps_per_s"]
        results.append(
            Result(
                NAME,
                f"{tag}: plant steps/s (4 units, 1 ms)",
                ours["steps_per_s"],
                "steps/s",
                "Basilisk VSCMG",
                pv,
                note="" if peer is not None else "Basilisk not installed: pip install -e '.[basilisk]'",
            )
        )
        results.append(
            Result(
                NAME,
                f"{tag}: simulated s per wall s",
                ours["steps_per_s"] * STEP,
                "x",
                "Basilisk VSCMG",
                None if pv is None else pv * STEP,
            )
        )
        results.append(
            Result(
                NAME,
                f"{tag}: momentum drift over {duration:g} s",
                ours["momentum_drift"],
                "rel",
                "Basilisk VSCMG",
                None if peer is None else peer["momentum_drift"],
                higher_is_better=False,
            )
        )
        if not driven:
            results.append(
                Result(
                    NAME,
                    f"free: energy drift over {duration:g} s",
                    ours["energy_drift"],
                    "rel",
                    "Basilisk VSCMG",
                    None if peer is None else peer["energy_drift"],
                    higher_is_better=False,
                )
            )
        compiled = _ours_compiled(duration, driven, per_call=False)
        per_call = _ours_compiled(duration, driven, per_call=True)
        diff = f"final state vs the numpy plant's: {_difference(compiled['final'], ours['final']):.1e} rel"
        for label, r in (("in one compiled call", compiled), ("one Python call per step", per_call)):
            results.append(
                Result(
                    NAME,
                    f"{tag}: compiled plant steps/s, {label}",
                    r["steps_per_s"],
                    "steps/s",
                    "Basilisk VSCMG",
                    pv,
                    note=diff,
                )
            )
        results.append(
            Result(
                NAME,
                f"{tag}: compiled plant steps/s vs the numpy Plant (B = 1)",
                compiled["steps_per_s"],
                "steps/s",
                "numpy Plant, B = 1",
                ours["steps_per_s"],
            )
        )
        if peer is not None:
            att, rate, gim = _agreement(ours["samples"], peer["samples"])
            results.append(
                Result(
                    NAME,
                    f"{tag}: max attitude difference vs Basilisk",
                    att,
                    "deg",
                    note=f"max body-rate diff {rate:.2e} rad/s, max gimbal-angle diff {gim:.2e} rad",
                )
            )
    results.append(
        Result(
            NAME,
            "batch of 64 runs: aggregate plant steps/s",
            _ours_batch(0.2 if quick else 1.0, 64),
            "steps/s",
        )
    )
    world = 1.0 if quick else 5.0
    ref_cost, _ = _world_cost(world / 5.0, compiled=False)
    for chunk in (0.001, 0.005):
        cost, batches = _world_cost(world, compiled=True, chunk=chunk)
        results.append(
            Result(
                NAME,
                f"world (plant, drives, phone, board): CPU s/simulated s, advanced every {chunk * 1e3:g} ms",
                cost,
                "CPU s/s",
                "world on the numpy references",
                ref_cost,
                higher_is_better=False,
                note=f"cubesat-1u, idle board in lockstep, 1 ms plant step, {batches / world:.0f} batches/s",
            )
        )
    results += _compile_cost()
    return results


if __name__ == "__main__":
    from bench.__main__ import format_table

    rows = run(quick=False)
    print(format_table(rows))
    for r in rows:
        if r.note:
            print(f"note {r.name}: {r.note}")
