"""The estimator's compiled kernels against their numpy references (hil.estimation.reference), to
rounding: random inputs for each kernel, then whole runs on simulated and on recorded phone/IMU data; the
live path equals the batch path bit for bit; and a smoke subset with compilation switched off."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hil import so3
from hil.estimation import chain, reference, reference_chain
from hil.estimation import variational as k
from hil.estimation.estimator import Estimate, VariationalEstimator
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.magnetic import MagneticGate, MagneticSettings
from hil.estimation.multirate import MergePolicy, first_full_step, merge
from hil.estimation.params import EstimatorParams, phi_log, wahba
from hil.estimation.prefilter import SignalPrefilter
from hil.estimation.sensors import MergedSteps, SensorKind, StepFlag
from hil.logs import read_log
from hil.scenario.paths import SHARED_DATA

ROOT = Path(__file__).resolve().parents[1]
FULL_D = np.array([[12.0, 2.0, -1.0], [2.0, 13.0, 0.5], [-1.0, 0.5, 14.0]])
PARAMS = {
    "paper": EstimatorParams.paper(),
    "full D, log Φ": EstimatorParams(D=FULL_D, phi=phi_log(2.0)),
    "bias law, delay": EstimatorParams(
        bias_gain=(0.02, 0.03, 0.01), bias_max=0.04, bias_vertical=1.7, gyro_delay_s=0.004
    ),
}


def random_vector(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """A 3-vector, sometimes unusable (NaN, zero) so every branch of the kernels is taken."""
    u = rng.random()
    if u < 0.08:
        return np.array([np.nan, 0.0, 1.0])
    if u < 0.12:
        return np.zeros(3)
    return scale * rng.normal(size=3)


# --------------------------------------------------------------------------- kernel by kernel
@pytest.mark.parametrize("name", PARAMS)
def test_measurement_and_torque_kernels_equal_the_reference(name):
    p = PARAMS[name]
    ep = k.pack_params(p)
    rng = np.random.default_rng(1)
    kinds = set()
    for i in range(400):
        acc, mag = random_vector(rng, 9.8), random_vector(rng, 45.0)
        if i % 25 == 0:  # (nearly) parallel: degenerate
            mag = acc * 3.0 + 1e-3 * rng.normal(size=3)
        weight = 1.0 if i % 3 else rng.uniform(0.0, 1.0)  # the field's weight (magnetic handling)
        ref = reference.measurement(p, acc, mag, weight)
        mask, big_l, kk, flags = k.measurement(ep, *acc.tolist(), *mag.tolist(), weight)
        assert (mask, flags) == (ref.mask, ref.flags)
        np.testing.assert_allclose(np.reshape(big_l, (3, 3)), ref.L, rtol=0, atol=1e-13)
        kinds.add(mask)
        r = so3.exp(rng.normal(size=3) * 2.0)
        tau = k.torque(ep, tuple(r.ravel()), big_l, mask, kk)
        np.testing.assert_allclose(tau, reference.torque(p, r, ref), rtol=0, atol=1e-12)
        if mask and p.phi.log_scale is not None:  # U⁰ = k − ⟨R̂, L⟩ against its definition
            u0 = kk - float(np.sum(r * np.reshape(big_l, (3, 3))))
            assert u0 == pytest.approx(reference.potential(p, r, ref), abs=1e-12)
    assert kinds == {0, 1, 2, 7}  # none, acc only, mag only, all three


@pytest.mark.parametrize("name", PARAMS)
def test_newton_and_advance_kernels_equal_the_reference(name):
    p = PARAMS[name]
    ep = k.pack_params(p)
    rng = np.random.default_rng(2)
    for _ in range(300):
        h = rng.uniform(1e-3, 0.05)
        g0, g1 = rng.normal(size=3) * 2.0, rng.normal(size=3) * 2.0
        w, tau0 = rng.normal(size=3) * 0.3, rng.normal(size=3) * 0.5
        r = so3.exp(rng.normal(size=3) * 2.0)
        acc, mag = rng.normal(size=3), rng.normal(size=3)
        ref_meas = reference.measurement(p, acc, mag)
        mask, big_l, kk, _ = k.measurement(ep, *acc.tolist(), *mag.tolist(), 1.0)
        c = rng.normal(size=3) * 0.2
        w_k, it_k, ok_k = k.newton(ep, 0.5 * h, tuple(g1), tuple(c))
        w_r, it_r, ok_r = reference.newton(p, 0.5 * h, g1, c)
        np.testing.assert_allclose(w_k, w_r, rtol=0, atol=1e-13)
        assert ok_k and ok_r and abs(it_k - it_r) <= 1
        b = rng.normal(size=3) * 0.01
        trust, up = rng.uniform(0.0, 1.0), acc / np.linalg.norm(acc)
        bl = (trust, *up.tolist())
        args = (
            tuple(r.ravel()),
            tuple(w),
            tuple(b),
            tuple(g0),
            tuple(tau0),
            h,
            tuple(g1),
            big_l,
            mask,
            kk,
            bl,
        )
        out = k.advance(ep, *args)
        ref = reference.advance(p, r, w, b, g0, tau0, h, g1, ref_meas, trust, up)
        np.testing.assert_allclose(np.reshape(out[0], (3, 3)), ref[0], rtol=0, atol=1e-13)
        for got, want in zip(out[1:4], ref[1:4], strict=True):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        assert out[5] and ref[5]


def test_prefilter_and_magnetic_kernels_equal_the_reference():
    rng = np.random.default_rng(3)
    n = 3000
    t = np.cumsum(rng.uniform(0.003, 0.007, n))
    h = np.diff(t, prepend=t[0])
    gyr = np.cumsum(rng.normal(size=(n, 3)) * 0.05, axis=0)
    acc = np.array([0.0, 0.0, 9.8]) + rng.normal(size=(n, 3))
    mag = np.array([0.0, 20.0, -40.0]) + rng.normal(size=(n, 3))
    acc[500:520] = np.nan  # drop-outs restart a filter
    mag[1000:1005, 1] = np.nan
    mag[1500:1700] *= 1.5  # a disturbance
    cut = {SensorKind.GYR: 5.0, SensorKind.ACC: 0.3, SensorKind.MAG: 1.0}
    for frame in ("body", "strapdown"):
        steps = MergedSteps(t, gyr, acc, mag, np.zeros((n, 3)), np.ones((n, 3), bool), np.zeros(n, np.int64))
        got = SignalPrefilter(cut, frame).run(steps)
        want = reference.signal_run(cut, frame, h, gyr, acc, mag)
        for g, w in zip((got.gyr, got.acc, got.mag), want, strict=True):
            np.testing.assert_allclose(g, w, rtol=0, atol=1e-9, equal_nan=True)
    settings = MagneticSettings(tau_s=5.0, steady_s=1.0, max_rejection_s=0.5, min_rate=0.5)
    rate = np.abs(gyr[:, 0])
    weights = MagneticGate(settings).run(h, rate, acc, mag)
    np.testing.assert_array_equal(weights, reference_chain.mag_run(settings, h, rate, acc, mag))
    assert weights[1550:1650].max() < 1.0 and weights[1800:].mean() > 0.95  # disturbance left out, then back


@pytest.mark.parametrize("preset", ["paper", "tuned"])
def test_wahba_kernel_equals_the_reference(preset):
    """The polar factor by Newton's iteration against numpy's SVD solution, for the paper's W and E and
    the tuned ones (W = diag(6, 1, 0.25), E with a horizontal e2)."""
    p = PARAMS["paper"] if preset == "paper" else FilterConfig.tuned(declination_deg=5.0).params
    ep = k.pack_params(p)
    rng = np.random.default_rng(4)
    for _ in range(200):
        acc, mag = rng.normal(size=3) * 9.8, rng.normal(size=3) * 45.0
        got = np.reshape(chain.wahba(ep, *acc.tolist(), *mag.tolist()), (3, 3))
        np.testing.assert_allclose(got, wahba(p, acc, mag), rtol=0, atol=2e-15 * 9)
        assert so3.orthonormality_error(got) < 1e-14


# --------------------------------------------------------------------------- whole runs
def noisy_steps(seed: int, n: int = 2000) -> MergedSteps:
    """Jittered steps with noise, drop-outs of each sensor, a degenerate stretch and long gaps."""
    rng = np.random.default_rng(seed)
    dt = rng.uniform(0.004, 0.006, n)
    dt[rng.choice(n, 6, replace=False)] = 0.13  # sub-stepped
    t = np.cumsum(dt)
    gyr = np.column_stack([np.sin(0.7 * t), 1.5 * np.cos(0.3 * t), 0.5 * np.sin(0.1 * t)])
    gyr = gyr + 0.02 * rng.normal(size=(n, 3))
    acc = np.array([0.3, 0.2, 9.8]) + 0.5 * rng.normal(size=(n, 3))
    mag = np.array([0.0, 20.0, -40.0]) + 2.0 * rng.normal(size=(n, 3))
    gyr[300:310] = np.nan
    acc[600:640] = np.nan
    mag[900:950] = np.nan
    mag[1200:1210] = acc[1200:1210] * 4.0  # parallel: degenerate
    acc[1400:1410] = mag[1400:1410] = np.nan  # no direction at all
    return MergedSteps(t, gyr, acc, mag, np.zeros((n, 3)), np.ones((n, 3), bool), np.zeros(n, np.int64))


@pytest.mark.parametrize("name", PARAMS)
def test_estimator_run_equals_the_reference_through_gaps_and_drop_outs(name):
    p = PARAMS[name]
    steps = noisy_steps(5)
    r0, w0, b0 = so3.exp([0.4, -1.0, 1.7]), np.array([0.01, -0.02, 0.005]), np.array([0.003, 0.0, -0.01])
    est = VariationalEstimator(p, r0, w0, b0)
    got = est.update_batch(steps)
    ref = reference.run(p, r0, w0, steps.t, steps.gyr, steps.acc, steps.mag, b0)
    np.testing.assert_allclose(got.R, ref.R, rtol=0, atol=1e-11)
    np.testing.assert_allclose(est.bias, ref.bias[-1], rtol=0, atol=1e-12)
    if any(p.bias_gain):
        assert np.linalg.norm(est.bias - b0) > 1e-3  # the bias law moved it
    np.testing.assert_allclose(got.omega_err, ref.omega_err, rtol=0, atol=1e-11)
    np.testing.assert_allclose(got.omega, ref.omega, rtol=0, atol=1e-11)
    np.testing.assert_array_equal(got.flags, ref.flags)
    assert np.mean(got.iterations == ref.iterations) > 0.99
    stats = est.stats
    assert (stats.substeps, stats.no_direction) == (ref.counters["substeps"], ref.counters["no_direction"])
    assert stats.substeps > 0 and stats.degenerate > 0 and stats.gyro_missing == 10
    assert stats.steps == len(steps) and stats.newton_updates == int(got.iterations.sum())


def test_per_sample_update_equals_the_batch_bit_for_bit():
    p = PARAMS["full D, log Φ"]
    steps = noisy_steps(6, 800)
    batch = VariationalEstimator(p).update_batch(steps)
    one = VariationalEstimator(p)
    h = steps.h
    live = [one.update(hi, g, a, m) for hi, g, a, m in zip(h, steps.gyr, steps.acc, steps.mag, strict=True)]
    np.testing.assert_array_equal(np.array([e.R for e in live]), batch.R)
    np.testing.assert_array_equal(np.array([e.omega for e in live]), batch.omega)
    np.testing.assert_array_equal([int(e.flags) for e in live], batch.flags)
    np.testing.assert_array_equal([e.iterations for e in live], batch.iterations)


RECORDED = [  # a recording, and where in its length the 60 s taken start
    (SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_Dist_Phoning", 0.0),
    (SHARED_DATA / "broad" / "24_disturbed_tapping_A.mat", 0.0),
    (SHARED_DATA / "broad" / "15_undisturbed_fast_translation_A.mat", 0.55),  # mid-motion: the settling
]


@pytest.fixture(scope="module", params=RECORDED, ids=lambda p: f"{p[0].name}@{p[1]}")
def recorded(request):
    path, start = request.param
    log = read_log(path)
    t0 = log.start + start * (log.end - log.start)
    log = log.window(t0, t0 + 60.0)
    steps, _ = merge(log.streams, MergePolicy(driver=SensorKind.GYR))
    return path.name, steps.rows(first_full_step(steps))


CHAIN_CONFIGS = {
    "paper": FilterConfig.paper(),
    "tuned": FilterConfig.tuned(declination_deg=2.0, gyro_bias=(1e-3, -2e-3, 5e-4)),
    "6-axis": FilterConfig.tuned(magnetometer="none"),
    "full field, body frame, no motion": FilterConfig.tuned(
        magnetometer="full",
        prefilter_frame="body",
        motion=None,
        params=EstimatorParams(bias_gain=(0.01,) * 3),
    ),
}


@pytest.mark.parametrize("preset", CHAIN_CONFIGS)
def test_filter_chain_equals_the_reference_on_recorded_data(recorded, preset):
    """The whole chain on 60 s of a real phone (tyrex, 199/199/50 Hz) and a real IMU (BROAD, 286 Hz,
    at rest, then tapped: magnetically disturbed): kernel vs the numpy reference (a per-step numpy
    transcription) to rounding, and the live path (one call per step) equal to the batch path bit for
    bit."""
    name, steps = recorded
    config = CHAIN_CONFIGS[preset]
    got = AttitudeFilter(config).run(steps, chunk=5000)
    ref = reference_chain.filter_run(config, steps)
    assert so3.orthonormality_error(got.R[-1]) < 1e-12
    angle = np.array([so3.angle_between(a, b) for a, b in zip(got.R[::50], ref.R[::50], strict=True)])
    assert angle.max() < 1e-8
    np.testing.assert_allclose(got.omega, ref.omega, rtol=0, atol=1e-8)
    np.testing.assert_array_equal(got.flags, ref.flags)
    if preset == "tuned" and "_Dist_" in name:  # a magnetically disturbed trial: the handling acts
        assert np.any(got.flags & StepFlag.MAG_DISTURBED)
    if preset == "tuned" and name.startswith("24_"):  # BROAD starts at rest: detected
        assert np.any(got.flags & StepFlag.REST)
    live = AttitudeFilter(config)
    first = [live.step(s) for s in steps.rows(0, 3000)]
    np.testing.assert_array_equal(np.array([e.R for e in first]), got.R[:3000])
    np.testing.assert_array_equal([int(e.flags) for e in first], got.flags[:3000])


# --------------------------------------------------------------------------- interpreted
def test_smoke_subset_passes_with_compilation_switched_off():
    """``NUMBA_DISABLE_JIT=1``: every kernel runs as the plain Python it is written in; the paper's check
    figure, a kernel-vs-reference comparison and the steering law still pass (slower)."""
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    selected = [
        "tests/test_estimator.py::test_paper_check_figure_127_to_15_to_1_5_degrees",
        "tests/test_estimator_kernels.py::test_newton_and_advance_kernels_equal_the_reference",
        "tests/test_estimator_kernels.py::test_per_sample_update_equals_the_batch_bit_for_bit",
        "tests/test_prefilter.py",
        "tests/test_steering.py",
    ]
    check = "import hil.jit, sys; sys.exit(0 if not hil.jit.COMPILED else 3)"
    assert subprocess.run([sys.executable, "-c", check], env=env, cwd=ROOT).returncode == 0
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *selected],
        env=env, cwd=ROOT, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]


def test_estimates_are_immutable_and_do_not_share_memory():
    est = VariationalEstimator()
    a = est.update(0.01, [0.0, 0.0, 0.5], [0, 0, 9.8], [0, 20, -40])
    b = est.update(0.01, (0.0, 0.0, 0.5), np.array([0, 0, 9.8]), [0, 20, -40])
    assert not np.shares_memory(a.R, b.R) and not np.array_equal(a.R, b.R)
    np.testing.assert_array_equal(b.omega, est.omega)
    with pytest.raises(AttributeError):
        a.t = 1.0  # type: ignore[misc]
    with pytest.raises(AttributeError):
        a.R = np.eye(3)  # type: ignore[misc]
    e = Estimate(0.5, np.eye(3), [1, 2, 3], [4, 5, 6], StepFlag.NONE, 2)
    np.testing.assert_array_equal(e.R, np.eye(3))
    np.testing.assert_array_equal(e.omega - e.omega_err, [-3, -3, -3])
    assert repr(e).startswith("Estimate(t=0.5, R=[[1.0, 0.0, 0.0]") and e.iterations == 2


def test_the_compiled_quaternions_are_the_numpy_references():
    """hil.estimation.quaternions.quats_of against hil.so3.matrix_to_quat: random rotations, every one of
    Shepperd's four branches (rotations by nearly π about each axis, and the identity), to rounding."""
    from hil.estimation.quaternions import quats_of

    rng = np.random.default_rng(7)
    vectors = rng.normal(size=(500, 3)) * rng.uniform(0.0, np.pi, (500, 1))
    branches = [np.zeros(3)] + [np.pi * (1 - 1e-9) * e for e in np.eye(3)] + [-np.pi * np.eye(3)[1]]
    R = so3.exp(np.concatenate([vectors, branches]))
    got, want = quats_of(R), so3.matrix_to_quat(R)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    assert np.all(got[:, 0] >= 0.0)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-15)
    assert np.argmax(np.abs(got[-4:-1, 1:]), axis=1).tolist() == [0, 1, 2]  # x, y, z branches taken
