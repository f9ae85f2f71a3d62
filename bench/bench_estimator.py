"""The paper's estimator against VQF, ahrs Madgwick and imufusion, in one run: accuracy on real data with
ground truth (the tyrex Nexus 5 smartphone trials and the BROAD trials), speed per step, and replay speed
on a 720k-sample log.

Accuracy: every algorithm sees the same merged steps (the gyroscope drives; accelerometer and
magnetometer held at gyro times, as the data README's figures were measured); estimates are interpolated to
the truth's timestamps and scored with BROAD's metric (RMSE of total / heading / inclination error, earth
frame) over each benchmark's evaluated samples (tyrex: motion-capture time 0–120 s minus the authors'
exclusions; BROAD: ``movement``). Our variants:

- ``ours-paper``: exactly the paper — its W, m, D, Φ(x) = x and the 1 rad/s body-frame pre-filter on all
  three signals; E from the log (measured field inclination, magnetic north).
- ``ours-paper-nopf``: the paper's gains without the pre-filter.
- ``ours-tuned``: the paper's estimator with :data:`hil.estimation.filter.TUNED` (gains, strapdown-frame
  pre-filter, horizontal magnetometer) and the gyro bias measured over the log's initial still window,
  found by :func:`tune` — a grid search on :data:`TUNING_TRIALS`; the other trials are held out.

Speed (per sample, batch, a 720k-sample replay, compile cost): :mod:`bench.estimator_speed`.
``python -m bench.bench_estimator --per-trial`` prints every trial's RMSE.

Peers with their default (or documented example) settings: VQF (C++, ``quat9D``; estimates its own gyro
bias), ahrs Madgwick (MARG, default gain; output NWU, converted to ENU), imufusion (the library's example
settings: gain 0.5, ±2000 °/s, rejection 10°, timeout 5 s; ENU).

``python -m bench.bench_estimator --tune`` re-runs the grid search (about half an hour).
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench import estimator_speed as speed
from bench.common import Result
from hil import so3
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.inertial import directions_from_dip, directions_from_log, find_still_window
from hil.estimation.metrics import AttitudeErrors, Rmse, resample_quats
from hil.estimation.multirate import MergePolicy, first_full_step, merge
from hil.estimation.params import PAPER_D, EstimatorParams
from hil.estimation.sensors import MergedSteps, SensorKind, SensorLog
from hil.logs import read_log
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

NAME = "estimator"
TYREX = SHARED_DATA / "tyrex-nexus5"
BROAD = SHARED_DATA / "broad"
TUNING_TRIALS = (
    "Guillaume_Nexus5_NoDist_Texting",
    "Guillaume_Nexus5_NoDist_RunningHand",
    "Guillaume_Nexus5_Dist_Phoning",
    "01_undisturbed_slow_rotation_A",
    "06_undisturbed_fast_rotation_A",
    "24_disturbed_tapping_A",
)
"""The trials the tuned parameters were chosen on; all others are held out."""


@dataclass
class Trial:
    name: str
    group: str
    log: SensorLog
    steps: MergedSteps
    inclination_deg: float
    gyro_bias: tuple[float, float, float]

    @property
    def held_out(self) -> bool:
        return self.name not in TUNING_TRIALS


def _trial(path: Path, group: str, window_s: tuple[float, float] | None) -> Trial:
    log = read_log(path)
    if window_s is not None:
        log = log.window(log.start + window_s[0], log.start + window_s[1])
    steps, _ = merge(log.streams, MergePolicy(driver=SensorKind.GYR))
    steps = steps.rows(first_full_step(steps))  # from when every sensor has spoken
    e, _ = directions_from_log(log)
    dip = math.degrees(math.asin(-float(e[2, 1])))
    try:
        still = find_still_window(log)
        gyr = log.streams[SensorKind.GYR]
        sel = (gyr.t >= still.t0) & (gyr.t <= still.t1)
        bias = tuple(float(x) for x in gyr.xyz[sel].mean(axis=0))
    except InputFormatError:
        bias = (0.0, 0.0, 0.0)
    return Trial(path.name.removesuffix(".mat"), group, log, steps, dip, bias)  # type: ignore[arg-type]


def load_trials(quick: bool = False, names: tuple[str, ...] | None = None) -> list[Trial]:
    """All tyrex and BROAD trials (``quick``: one of each, 30 s of motion)."""
    paths: list[tuple[Path, str]] = []
    for p in sorted(TYREX.iterdir()) if TYREX.is_dir() else []:
        if p.is_dir():
            paths.append((p, "tyrex-dist" if "_Dist_" in p.name else "tyrex-nodist"))
    for p in sorted(BROAD.glob("*.mat")) if BROAD.is_dir() else []:
        paths.append(
            (
                p,
                "broad-disturbed"
                if "disturbed_" in p.name and "undisturbed" not in p.name
                else "broad-undisturbed",
            )
        )
    if names is not None:
        paths = [(p, g) for p, g in paths if p.name.removesuffix(".mat") in names]
    if quick:
        paths = [p for p in paths if p[0].name.startswith(("Guillaume_Nexus5_NoDist_Texting", "01_"))]
    # quick: 30 s of motion (BROAD trials start with ~34 s at rest, not evaluated)
    return [
        _trial(p, g, ((30.0, 60.0) if g.startswith("broad") else (0.0, 30.0)) if quick else None)
        for p, g in paths
    ]


# --------------------------------------------------------------------------- algorithms
def _ours(config: Callable[[Trial], FilterConfig]) -> Callable[[Trial], np.ndarray]:
    def run(trial: Trial) -> np.ndarray:
        return AttitudeFilter(config(trial)).run(trial.steps).quat

    return run


def _paper(trial: Trial) -> FilterConfig:
    return FilterConfig.paper(E=directions_from_dip(trial.inclination_deg))


def _paper_nopf(trial: Trial) -> FilterConfig:
    return FilterConfig.paper(E=directions_from_dip(trial.inclination_deg), prefilter_rad_s={})


def _tuned(trial: Trial) -> FilterConfig:
    return FilterConfig.tuned(gyro_bias=trial.gyro_bias)


def _arrays(steps: MergedSteps) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    fill = lambda a: np.ascontiguousarray(np.nan_to_num(a))  # noqa: E731  (peers cannot take NaN)
    return fill(steps.gyr), fill(steps.acc), fill(steps.mag), float(np.median(np.diff(steps.t)))


def vqf_quats(trial: Trial) -> np.ndarray:
    from vqf import VQF

    gyr, acc, mag, dt = _arrays(trial.steps)
    return VQF(dt).updateBatch(gyr, acc, mag)["quat9D"]


_NWU_TO_ENU = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def madgwick_quats(trial: Trial) -> np.ndarray:
    from ahrs.filters import Madgwick

    gyr, acc, mag, dt = _arrays(trial.steps)
    q = Madgwick(gyr=gyr, acc=acc, mag=mag, frequency=1.0 / dt).Q  # sensor → NWU
    return so3.matrix_to_quat(_NWU_TO_ENU @ so3.quat_to_matrix(q))


def imufusion_ahrs(rate_hz: float):  # type: ignore[no-untyped-def]
    import imufusion

    ahrs = imufusion.Ahrs()
    settings = imufusion.AhrsSettings()
    settings.convention = imufusion.CONVENTION_ENU
    settings.gain = 0.5
    settings.gyroscope_range = 2000.0
    settings.acceleration_rejection = 10.0
    settings.magnetic_rejection = 10.0
    settings.rejection_timeout = 5.0
    settings.sample_rate = rate_hz
    ahrs.set_settings(settings)
    return ahrs


def imufusion_quats(trial: Trial) -> np.ndarray:
    gyr, acc, mag, dt = _arrays(trial.steps)
    ahrs = imufusion_ahrs(1.0 / dt)
    gyr_deg, acc_g = np.degrees(gyr), acc / 9.80665
    out = np.empty((len(gyr), 4))
    for i in range(len(gyr)):
        ahrs.update(gyr_deg[i], acc_g[i], mag[i])
        out[i] = ahrs.get_quaternion()
    return out


ALGORITHMS: dict[str, Callable[[Trial], np.ndarray]] = {
    "ours-paper": _ours(_paper),
    "ours-paper-nopf": _ours(_paper_nopf),
    "ours-tuned": _ours(_tuned),
    "VQF": vqf_quats,
    "Madgwick": madgwick_quats,
    "imufusion": imufusion_quats,
}


def score(trial: Trial, quats: np.ndarray) -> Rmse:
    truth = trial.log.truth
    assert truth is not None
    q_est = resample_quats(trial.steps.t, quats, truth.t)
    finite = np.all(np.isfinite(truth.R.reshape(len(truth), 9)), axis=1)
    q_ref = np.full((len(truth), 4), np.nan)
    q_ref[finite] = so3.matrix_to_quat(truth.R[finite])
    mask = np.asarray(truth.evaluate) & finite & np.all(np.isfinite(q_est), axis=1)
    return AttitudeErrors.from_quats(q_est, q_ref).rmse(mask)


def accuracy(trials: list[Trial], algorithms: dict[str, Callable[[Trial], np.ndarray]]) -> dict:
    """``{algorithm: {trial name: Rmse}}``."""
    return {name: {t.name: score(t, fn(t)) for t in trials} for name, fn in algorithms.items()}


def _mean(rmses: list[Rmse]) -> tuple[float, float, float]:
    return tuple(float(np.mean([getattr(r, f) for r in rmses])) for f in ("total", "heading", "inclination"))  # type: ignore[return-value]


# --------------------------------------------------------------------------- tuning
def tune(trials: list[Trial]) -> list[tuple[float, dict]]:
    """Grid search of the tuned settings on ``trials``: minimises the mean total RMSE (BROAD's "TAGP"
    idea: one parameter set for all trials). Returns (score, settings) sorted best first."""
    grid = {  # stage 2; stage 1 (w_acc 1.5–12, w_mag 0.5–2, w_cross 0.25/1, d_scale 0.5–2, acc cut-off
        # 0.15–0.6, mag cut-off none/0.5) favoured low damping, no magnetometer pre-filter, small w_cross
        "w_acc": (1.5, 3.0, 6.0),
        "w_mag": (0.5, 1.0, 2.0),
        "w_cross": (0.25,),
        "d_scale": (0.25, 0.5),
        "acc_cutoff": (0.15, 0.3),
        "mag_cutoff": (None,),
        "m": (0.1, 0.5),
    }
    results = []
    for values in itertools.product(*grid.values()):
        s = dict(zip(grid, values, strict=True))
        diag = (s["w_acc"], s["w_mag"], s["w_cross"])
        if len(set(diag)) < 3:
            continue
        cfg_of = _tuned_config(diag, s["d_scale"], s["acc_cutoff"], s["mag_cutoff"], s["m"])
        rmses = [score(t, AttitudeFilter(cfg_of(t)).run(t.steps).quat) for t in trials]
        results.append((_mean(rmses)[0], s))
        print(f"{results[-1][0]:7.3f}  {s}", file=sys.stderr, flush=True)
    return sorted(results, key=lambda r: r[0])


def _tuned_config(w_diag, d_scale, acc_cutoff, mag_cutoff, m):  # type: ignore[no-untyped-def]
    def config(trial: Trial) -> FilterConfig:
        base = FilterConfig.tuned(gyro_bias=trial.gyro_bias)
        params = EstimatorParams(
            E=base.params.E, W=np.diag(w_diag), m=m, D=np.diag(np.diag(PAPER_D)) * d_scale
        )
        cut = {SensorKind.ACC: acc_cutoff, SensorKind.MAG: mag_cutoff, SensorKind.GYR: None}
        return FilterConfig.tuned(gyro_bias=trial.gyro_bias, params=params, prefilter_rad_s=cut)

    return config


# --------------------------------------------------------------------------- the benchmark
def run(quick: bool) -> list[Result]:
    results: list[Result] = []
    trials = load_trials(quick)
    if not trials:
        return [Result(NAME, "no shared data", 0.0, "", note=f"{SHARED_DATA} not found")]
    acc = accuracy(trials, ALGORITHMS)
    groups = sorted({t.group for t in trials})
    for group in groups + ["held-out"]:
        members = [t for t in trials if (t.group == group if group != "held-out" else t.held_out)]
        if not members:
            continue
        means = {a: _mean([acc[a][t.name] for t in members]) for a in ALGORITHMS}
        detail = "; ".join(f"{a} {m[0]:.2f}/{m[1]:.2f}/{m[2]:.2f}" for a, m in means.items())
        for name in ("ours-tuned", "ours-paper-nopf", "ours-paper", "Madgwick", "imufusion"):
            note = detail if name == "ours-tuned" else ""
            label = f"{group} ({len(members)}) RMSE total, {name}"
            results.append(Result(NAME, label, means[name][0], "deg", "VQF", means["VQF"][0], False, note))
    results += speed_results(trials[0], quick)
    return results


def speed_results(trial: Trial, quick: bool) -> list[Result]:
    """Per-sample, batch, replay and compile figures (:mod:`bench.estimator_speed`), in this run."""
    results: list[Result] = []
    e = directions_from_dip(trial.inclination_deg)
    step = speed.step_speed(trial.steps, e, 2000 if quick else 20000, imufusion_ahrs)
    notes = {
        "ours": "VariationalEstimator.update: the estimator alone, one compiled call",
        "ours chain": "AttitudeFilter.step (tuned): bias, strapdown pre-filter, gate, horizontal mag",
    }
    for ours, note in notes.items():
        for peer in ("VQF", "PyVQF", "Madgwick", "imufusion"):
            results.append(Result(NAME, f"per-sample {ours}", step[ours], "us/step", peer, step[peer], False,
                                  note))  # fmt: skip
    walls, steps, n = speed.replay_speed(20_000 if quick else 720_000)
    batch = speed.batch_speed(steps, imufusion_ahrs, 2000 if quick else 30000)
    notes = {"ours": "VariationalEstimator.update_batch", "ours chain": "AttitudeFilter.run, tuned"}
    for ours, note in notes.items():
        for peer in ("VQF", "offlineVQF", "Madgwick", "imufusion"):
            label = f"batch {ours}, {len(steps)} steps"
            results.append(
                Result(NAME, label, batch[ours], "us/step", f"{peer} batch", batch[peer], False, note)
            )
    for stage in ("read", "merge", "filter", "merge + filter", "end to end"):
        note = "target <= 1.5 s" if stage == "merge + filter" else ""
        if stage == "end to end":
            note = "hil.logs.replay: read CSV, merge, tuned filter, write estimates CSV"
        results.append(Result(NAME, f"replay {n} samples: {stage}", walls[stage], "s", note=note))
    cost = speed.compile_cost()
    for label in ("cold", "warm"):
        what = "compiled into an empty cache" if label == "cold" else "loaded from the cache"
        imports, cpu = cost[f"{label} import"], cost[f"{label} cpu"]
        note = f"fresh process, {what}; import {imports:.2f} s; process CPU {cpu:.1f} s"
        results.append(Result(NAME, f"kernels ready, {label}", cost[f"{label} kernels"], "s", note=note))
    return results


def per_trial_table(trials: list[Trial]) -> str:
    """Every trial's RMSE total / heading / inclination (deg) for every algorithm."""
    acc = accuracy(trials, ALGORITHMS)
    lines = ["trial  " + "  ".join(ALGORITHMS)]
    for t in trials:
        cells = [f"{acc[a][t.name].total:.4f}/{acc[a][t.name].heading:.4f}/{acc[a][t.name].inclination:.4f}"
                 for a in ALGORITHMS]  # fmt: skip
        lines.append(f"{t.name}  " + "  ".join(cells))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.bench_estimator")
    parser.add_argument("--tune", action="store_true", help="grid-search the tuned settings on TUNING_TRIALS")
    parser.add_argument(
        "--per-trial", action="store_true", help="print every trial's RMSE, not the benchmark"
    )
    args = parser.parse_args(argv)
    if args.per_trial:
        print(per_trial_table(load_trials()))
        return 0
    if args.tune:
        os.nice(5)
        best = tune(load_trials(names=TUNING_TRIALS))
        for value, settings in best[:10]:
            print(f"{value:.3f}  {settings}")
        return 0
    from bench.__main__ import format_table

    print(format_table(run(quick=False)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
