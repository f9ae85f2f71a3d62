"""Speed of the compiled estimator against its peers, for :mod:`bench.bench_estimator` (same run):

- **per sample** (µs): ``VariationalEstimator.update`` (the estimator alone) and ``AttitudeFilter.step``
  (the host's live path: bias, tuned strapdown pre-filter, gate, horizontal magnetometer, estimator),
  one Python call per sample each, against VQF's C++ core (``VQF.update`` + ``getQuat9D``), PyVQF,
  ahrs Madgwick (``updateMARG``) and imufusion (``update`` + ``get_quaternion``);
- **batch** (µs per merged step, over a long log): ``VariationalEstimator.update_batch`` and
  ``AttitudeFilter.run`` against VQF's ``updateBatch`` and ``offlineVQF``, ahrs Madgwick's batch and
  imufusion's per-sample loop (it has no batch API);
- **replay of a 720k-sample log** (wall s): tyrex trials end to end in the project CSV; read, merge, the
  tuned filter, and ``hil.logs.replay`` end to end (read, merge, filter, write the estimates CSV);
- **compile cost** (s): the estimator's and steering's kernels compiled into an empty numba cache in a
  fresh process (a fresh install's first run), then loaded from that cache by a second process.
"""

from __future__ import annotations

import itertools
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hil.estimation.estimator import VariationalEstimator
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.multirate import first_full_step, merge
from hil.estimation.params import EstimatorParams
from hil.estimation.sensors import MergedSteps, SensorKind, SensorLog
from hil.logs import read_log
from hil.scenario.paths import ROOT, SHARED_DATA

TYREX = SHARED_DATA / "tyrex-nexus5"


def us_per_call(fn: Callable[[int], None], n: int, repeat: int = 5) -> float:
    """Best of ``repeat`` runs of ``fn(n)``, in µs per step (a warm-up run first)."""
    fn(min(n, 100))
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn(n)
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def _peer_arrays(steps: MergedSteps) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    fill = lambda a: np.ascontiguousarray(np.nan_to_num(a))  # noqa: E731  (peers cannot take NaN)
    return fill(steps.gyr), fill(steps.acc), fill(steps.mag), float(np.median(np.diff(steps.t)))


def step_speed(steps: MergedSteps, E: np.ndarray, n: int, imufusion_ahrs: Callable) -> dict[str, float]:  # type: ignore[type-arg]
    """µs per sample through each per-sample API, on the first ``n`` merged steps."""
    from ahrs.filters import Madgwick
    from vqf import VQF, PyVQF

    steps = steps.rows(0, n)
    gyr, acc, mag, dt = _peer_arrays(steps)
    g, a, m = gyr.tolist(), acc.tolist(), mag.tolist()
    live = list(steps)

    def ours(k: int) -> None:
        est = VariationalEstimator(EstimatorParams(E=E))
        for i in range(k):
            est.update(dt, g[i], a[i], m[i])

    def chain(k: int) -> None:
        f = AttitudeFilter(FilterConfig.tuned())
        for s in live[:k]:
            f.step(s)

    def vqf_cpp(k: int) -> None:
        v = VQF(dt)
        for i in range(k):
            v.update(gyr[i], acc[i], mag[i])
            v.getQuat9D()

    def vqf_py(k: int) -> None:
        v = PyVQF(dt)
        for i in range(k):
            v.update(gyr[i], acc[i], mag[i])
            v.getQuat9D()

    def madgwick(k: int) -> None:
        f = Madgwick(frequency=1.0 / dt)
        q = np.array([1.0, 0.0, 0.0, 0.0])
        for i in range(k):
            q = f.updateMARG(q, gyr[i], acc[i], mag[i])

    def fusion(k: int) -> None:
        ahrs = imufusion_ahrs(1.0 / dt)
        gd, ag = np.degrees(gyr), acc / 9.80665
        for i in range(k):
            ahrs.update(gd[i], ag[i], mag[i])
            ahrs.get_quaternion()

    return {
        "ours": us_per_call(ours, n),
        "ours chain": us_per_call(chain, n),
        "VQF": us_per_call(vqf_cpp, n),
        "PyVQF": us_per_call(vqf_py, max(n // 20, 50), 3),
        "Madgwick": us_per_call(madgwick, max(n // 5, 50), 3),
        "imufusion": us_per_call(fusion, n),
    }


def batch_speed(steps: MergedSteps, imufusion_ahrs: Callable, slow_steps: int) -> dict[str, float]:  # type: ignore[type-arg]
    """µs per merged step of each batch API over all of ``steps`` (best of three); ahrs Madgwick (its
    batch constructor) and imufusion (no batch API: its per-sample loop) once, on the first
    ``slow_steps``."""
    from ahrs.filters import Madgwick
    from vqf import VQF, offlineVQF

    gyr, acc, mag, dt = _peer_arrays(steps)
    runs: dict[str, Callable[[], object]] = {
        "ours": lambda: VariationalEstimator().update_batch(steps),
        "ours chain": lambda: AttitudeFilter(FilterConfig.tuned()).run(steps),
        "VQF": lambda: VQF(dt).updateBatch(gyr, acc, mag),
        "offlineVQF": lambda: offlineVQF(gyr, acc, mag, dt),
    }
    out = {}
    for name, fn in runs.items():
        fn()
        best = math.inf
        for _ in range(3):
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
        out[name] = best / len(steps) * 1e6
    g, a, m = gyr[:slow_steps], acc[:slow_steps], mag[:slow_steps]

    def fusion() -> None:
        ahrs = imufusion_ahrs(1.0 / dt)
        gd, ag = np.degrees(g), a / 9.80665
        for i in range(len(g)):
            ahrs.update(gd[i], ag[i], m[i])
            ahrs.get_quaternion()

    for name, fn in (
        ("Madgwick", lambda: Madgwick(gyr=g, acc=a, mag=m, frequency=1.0 / dt)),
        ("imufusion", fusion),
    ):
        t0 = time.perf_counter()
        fn()
        out[name] = (time.perf_counter() - t0) / len(g) * 1e6
    return out


def long_log(samples: int, directory: Path) -> Path:
    """A ``samples``-sample phone log in the project CSV: tyrex trials end to end (times shifted)."""
    from hil.estimation.sensors import SensorStream
    from hil.logs import project_csv

    parts: dict[SensorKind, list[SensorStream]] = {k: [] for k in SensorKind}
    total, offset = 0, 0.0
    trials = sorted(p for p in TYREX.iterdir() if p.is_dir())
    for path in itertools.cycle(trials):
        log = read_log(path)
        for k, s in log.streams.items():
            parts[k].append(s.shifted(offset - log.start))
        total += log.n_samples
        offset += log.end - log.start + 1.0
        if total >= samples:
            break
    streams = {
        k: SensorStream(k, np.concatenate([s.t for s in v]), np.concatenate([s.xyz for s in v]))
        for k, v in parts.items()
    }
    joined = SensorLog(streams, "tyrex trials concatenated", "csv")
    return project_csv.write(joined, directory / "long.csv")


def replay_speed(samples: int) -> tuple[dict[str, float], MergedSteps, int]:
    """Wall seconds of each stage of replaying a ``samples``-sample log (best of two), the merged steps and
    the sample count."""
    from hil.logs.replay import ReplayOptions, replay

    with tempfile.TemporaryDirectory() as tmp:
        path = long_log(samples, Path(tmp))
        replay(path, ReplayOptions(out_dir=Path(tmp) / "warm"))  # kernels loaded, files cached
        walls: dict[str, float] = {}
        for _ in range(2):
            t0 = time.perf_counter()
            log = read_log(path)
            t1 = time.perf_counter()
            steps, _ = merge(log.streams)
            steps = steps.rows(first_full_step(steps))
            t2 = time.perf_counter()
            AttitudeFilter(FilterConfig.tuned()).run(steps)
            t3 = time.perf_counter()
            replay(path, ReplayOptions(out_dir=Path(tmp) / "out"))
            t4 = time.perf_counter()
            stages = {"read": t1 - t0, "merge": t2 - t1, "filter": t3 - t2, "merge + filter": t3 - t1,
                      "end to end": t4 - t3}  # fmt: skip
            walls = {k: min(v, walls.get(k, math.inf)) for k, v in stages.items()}
        return walls, steps, log.n_samples


_COMPILE_PROBE = """
import time
t0 = time.perf_counter()
import numpy as np
from hil.control.steering import VscmgSteering
from hil.estimation.estimator import VariationalEstimator
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.sensors import MergedSteps
from hil.vscmg import cubesat_1u
t1 = time.perf_counter()
n = 50
t = np.arange(n) * 0.005
acc, mag = np.tile([0.0, 0.0, 9.8], (n, 1)), np.tile([0.0, 20.0, -40.0], (n, 1))
steps = MergedSteps(t, np.full((n, 3), 0.1), acc, mag, np.zeros((n, 3)), np.ones((n, 3), bool),
                    np.zeros(n, np.int64))
VariationalEstimator().update_batch(steps)
e = VariationalEstimator()
e.update(0.005, [0.1, 0.0, 0.0], [0.0, 0.0, 9.8], [0.0, 20.0, -40.0])
for config in (FilterConfig.tuned(), FilterConfig.paper()):
    f = AttitudeFilter(config)
    f.step(steps[0])
    f.run(steps.rows(1))
VscmgSteering(cubesat_1u()).solve([1e-4, 0.0, 0.0], np.zeros(4), np.full(4, 400.0), 0.02)
print(t1 - t0, time.perf_counter() - t1)
"""


def compile_cost() -> dict[str, float]:
    """Seconds to import the estimator and steering, and to get every kernel they call ready: with an
    empty numba cache (compiled), then from that cache (loaded). Each in a fresh process, whose CPU
    seconds (user + system, the whole process) are given too: on a loaded machine they, not the wall
    time, say what the compiler costs."""
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for label in ("cold", "warm"):
            argv = [sys.executable, "-c", _COMPILE_PROBE]
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            proc = subprocess.run(argv, env=env, cwd=ROOT, capture_output=True, text=True, check=True)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            imports, ready = (float(x) for x in proc.stdout.split())
            out[f"{label} import"], out[f"{label} kernels"] = imports, ready
            out[f"{label} cpu"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return out
