"""The paper's estimator, tuned, against VQF, ahrs Madgwick and imufusion, in one run: accuracy on real data
with ground truth (the tyrex Nexus 5 smartphone trials and the BROAD trials), speed per step, and replay
speed on a 720k-sample log.

Accuracy: every algorithm sees the same merged steps (the gyroscope drives; accelerometer and
magnetometer held at gyro times, as the data README's figures were measured); estimates are interpolated to
the truth's timestamps and scored with BROAD's metric (RMSE of total / heading / inclination error, earth
frame) over each benchmark's evaluated samples (tyrex: motion-capture time 0–120 s minus the authors'
exclusions; BROAD: ``movement``). Groups: the smartphone trials (none has a still window), the BROAD
trials as recorded (each starts with ~30 s at rest), and the same BROAD trials from their first motion
(no still window left for anyone). Our variants:

- ``ours``: :meth:`hil.estimation.filter.FilterConfig.tuned` online only — no still window given: the
  bias is the estimator's own (at rest and in motion) — as ``hil replay --gyro-bias none`` runs it;
- ``ours+still``: the same with the bias measured over the log's initial still window as the
  initialiser (``hil replay``'s default; the same as ``ours`` on logs without one);
- ``ours-paper``: exactly the paper — its W, m, D, Φ(x) = x and the 1 rad/s body-frame pre-filter on all
  three signals; E from the log (measured field inclination, magnetic north).

The tuned preset's parameters come from :mod:`bench.estimator_tuning` (``--tune``). ``--per-trial`` prints
every trial's RMSE; the summary rows also give ours through ``hil replay``'s own path
(:func:`hil.logs.replay.replay`: its merge, its configuration) on the as-recorded trials.

Speed (per sample, batch, a 720k-sample replay, compile cost): :mod:`bench.estimator_speed`.

Peers with their default (or documented example) settings: VQF (C++, ``quat9D``; estimates its own gyro
bias), ahrs Madgwick (MARG, default gain; output NWU, converted to ENU), imufusion (the library's example
settings: gain 0.5, ±2000 °/s, rejection 10°, timeout 5 s; ENU).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench import estimator_speed as speed
from bench import estimator_tuning as tuning
from bench.common import Result
from hil import so3
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.inertial import directions_from_dip, directions_from_log, find_still_window
from hil.estimation.metrics import AttitudeErrors, Rmse, resample_quats
from hil.estimation.multirate import MergePolicy, first_full_step, merge
from hil.estimation.sensors import MergedSteps, SensorKind, SensorLog
from hil.logs import read_log
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

NAME = "estimator"
TYREX = SHARED_DATA / "tyrex-nexus5"
BROAD = SHARED_DATA / "broad"
GROUPS = ("smartphone", "BROAD", "BROAD from first motion")


@dataclass
class Trial:
    name: str
    group: str
    log: SensorLog
    steps: MergedSteps
    inclination_deg: float
    gyro_bias: tuple[float, float, float]
    path: Path

    @property
    def family(self) -> str:
        """``smartphone``, ``BROAD`` or ``BROAD from first motion``."""
        if self.group.startswith("tyrex"):
            return "smartphone"
        return "BROAD from first motion" if self.name.endswith("(from first motion)") else "BROAD"


def _trial(path: Path, group: str, window_s: tuple[float, float] | None) -> Trial:
    log = read_log(path)
    if window_s is not None:
        log = log.window(log.start + window_s[0], log.start + window_s[1])
    return _trial_of(log, path, path.name.removesuffix(".mat"), group)


def from_first_motion(trial: Trial) -> Trial:
    """The trial from its first evaluated (moving) sample on: no still window left."""
    truth = trial.log.truth
    assert truth is not None and truth.evaluate is not None
    t0 = float(truth.t[np.argmax(truth.evaluate)])
    log = trial.log.window(t0, trial.log.end)
    return _trial_of(log, trial.path, f"{trial.name} (from first motion)", trial.group)


def _trial_of(log: SensorLog, path: Path, name: str, group: str) -> Trial:
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
    return Trial(name, group, log, steps, dip, bias, path)  # type: ignore[arg-type]


def load_trials(quick: bool = False, cropped: bool = True) -> list[Trial]:
    """All tyrex and BROAD trials, and (``cropped``) the BROAD ones again from their first motion
    (``quick``: one of each, 30 s of motion)."""
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
    if quick:
        paths = [p for p in paths if p[0].name.startswith(("Guillaume_Nexus5_NoDist_Texting", "01_"))]
    # quick: 30 s of motion (BROAD trials start with ~34 s at rest, not evaluated)
    trials = [
        _trial(p, g, ((30.0, 60.0) if g.startswith("broad") else (0.0, 30.0)) if quick else None)
        for p, g in paths
    ]
    return trials + [from_first_motion(t) for t in trials if cropped and t.group.startswith("broad")]


# --------------------------------------------------------------------------- algorithms
def _ours(config: Callable[[Trial], FilterConfig]) -> Callable[[Trial], np.ndarray]:
    def run(trial: Trial) -> np.ndarray:
        return AttitudeFilter(config(trial)).run(trial.steps).quat

    return run


def _paper(trial: Trial) -> FilterConfig:
    return FilterConfig.paper(E=directions_from_dip(trial.inclination_deg))


def _tuned(trial: Trial) -> FilterConfig:
    return FilterConfig.tuned()


def _tuned_still(trial: Trial) -> FilterConfig:
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
    "ours": _ours(_tuned),
    "ours+still": _ours(_tuned_still),
    "ours-paper": _ours(_paper),
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


# --------------------------------------------------------------------------- the benchmark
def replay_rmse(trial: Trial, gyro_bias: str) -> Rmse:
    """Ours through ``hil replay``'s own path on a trial as recorded (its merge, its configuration)."""
    from hil.logs.replay import ReplayOptions, replay

    with tempfile.TemporaryDirectory() as tmp:
        result = replay(trial.path, ReplayOptions(out_dir=Path(tmp), gyro_bias=gyro_bias))
    assert result.comparison is not None
    return result.comparison.rmse


def run(quick: bool) -> list[Result]:
    results: list[Result] = []
    trials = load_trials(quick)
    if not trials:
        return [Result(NAME, "no shared data", 0.0, "", note=f"{SHARED_DATA} not found")]
    acc = accuracy(trials, ALGORITHMS)
    for family in GROUPS:
        members = [t for t in trials if t.family == family]
        if not members:
            continue
        means = {a: _mean([acc[a][t.name] for t in members]) for a in ALGORITHMS}
        detail = "; ".join(f"{a} {m[0]:.2f}/{m[1]:.2f}/{m[2]:.2f}" for a, m in means.items())
        names = ["ours"] if family == "BROAD from first motion" else ["ours", "ours+still"]
        for name in [*names, "ours-paper", "Madgwick", "imufusion"]:
            for k, part in enumerate(("total", "heading", "inclination")):
                if part != "total" and not name.startswith("ours"):
                    continue
                note = detail if (name, part) == ("ours", "total") else ""
                label = f"{family} ({len(members)}) RMSE {part}, {name}"
                results.append(
                    Result(NAME, label, means[name][k], "deg", "VQF", means["VQF"][k], False, note)
                )
        if family != "BROAD from first motion" and not quick:
            for bias in ("none", "still"):
                rm = _mean([replay_rmse(t, bias) for t in members])
                label = f"{family} ({len(members)}) RMSE total, hil replay --gyro-bias {bias}"
                results.append(Result(NAME, label, rm[0], "deg", "VQF", means["VQF"][0], False,
                                      f"{rm[0]:.2f}/{rm[1]:.2f}/{rm[2]:.2f}"))  # fmt: skip
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
    parser.add_argument(
        "--tune", action="store_true", help="choose the tuned preset (bench.estimator_tuning), ~30 min"
    )
    parser.add_argument(
        "--per-trial", action="store_true", help="print every trial's RMSE, not the benchmark"
    )
    args = parser.parse_args(argv)
    if args.per_trial:
        print(per_trial_table(load_trials()))
        return 0
    if args.tune:
        os.nice(5)
        trials = load_trials(cropped=False)
        vqf = np.array([[(r := score(t, vqf_quats(t))).total, r.heading, r.inclination] for t in trials])
        result = tuning.tune(trials, vqf, score)
        print(json.dumps({"preset": result["preset"], "summary": result["summary"]}, indent=1))
        return 0
    from bench.__main__ import format_table

    print(format_table(run(quick=False)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
