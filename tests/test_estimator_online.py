"""The estimator's online stages: the gyro bias law (its analytic case and Lyapunov function), rest
detection, the accelerometer's trust, the still window as an optional initialiser, and the 6-axis mode."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from firmware_sim.world.models import Trajectory, paper_testbed_rate, simulate
from hil import so3
from hil.estimation import motion as mo
from hil.estimation import reference, reference_chain
from hil.estimation.estimator import VariationalEstimator
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.metrics import AttitudeErrors
from hil.estimation.motion import MotionSettings, motion_step, pack_motion_params
from hil.estimation.multirate import MergePolicy, first_full_step, merge
from hil.estimation.params import EstimatorParams, paper_initial_attitude
from hil.estimation.sensors import MergedSteps, SensorKind, StepFlag
from hil.scenario.phone import PhoneSpec
from protocol.errors import ConfigError
from tests.test_estimator import body_directions, steps_of, trajectory

BIAS = np.array([0.01, -0.02, 0.015])  # rad/s, 0.6–1.1 °/s: a poor phone gyro's
GAIN = 0.05


def noise_free_run(gain: float, duration: float = 120.0):
    """The paper's case (its E, W, m, D, 127° start, ω0) with a constant gyro bias and the bias law at
    ``gain``; returns times, true attitudes, the estimator and the Lyapunov function along the run."""
    h = 0.01
    t, rs, rates = trajectory(h, duration)
    p = EstimatorParams(bias_gain=(gain,) * 3)
    acc, mag = body_directions(p, rs)
    est = VariationalEstimator(p, R0=paper_initial_attitude(rs[0]), omega_err0=(0.001, 0.002, -0.003))
    lyapunov, estimates = [], []
    for i in range(len(t)):
        e = est.update(h if i else 0.0, rates[i] + BIAS, acc[i], mag[i])
        estimates.append(e.R)
        u0 = reference.potential(p, e.R, reference.measurement(p, acc[i], mag[i]))
        b_err = BIAS - est.bias
        bias_term = 0.5 * float(b_err @ b_err) / gain if gain else 0.0
        lyapunov.append(0.5 * p.m * float(e.omega_err @ e.omega_err) + u0 + bias_term)
    angles = np.degrees([so3.angle_between(a, b) for a, b in zip(rs, estimates, strict=True)])
    return t, angles, est, np.array(lyapunov)


def test_bias_law_converges_to_a_constant_bias_and_its_lyapunov_function_never_rises():
    """``db̂/dt = P⁻¹ Φ' S_L`` makes ``V = ½ m ωᵀω + Φ(U⁰) + ½ b̃ᵀ P b̃`` decrease (continuous time:
    ``V̇ = −ωᵀ D ω``): on the noise-free paper case from 127° the discrete V never rises above rounding,
    b̂ converges to the true bias and the attitude to the truth."""
    t, angles, est, v = noise_free_run(GAIN)
    assert angles[0] == pytest.approx(126.8, abs=0.5)
    assert np.max(np.diff(v)) < 1e-12 * v[0]  # monotone to rounding
    assert v[-1] < 1e-10 * v[0]
    np.testing.assert_allclose(est.bias, BIAS, rtol=0, atol=1e-6)
    assert angles[-1] < 1e-3


def test_without_the_bias_law_the_estimate_keeps_an_offset():
    """The same run with the paper's estimator (no bias term): it settles with a steady error (the
    torque has to supply the bias), and b̂ stays where it started."""
    _, angles, est, _ = noise_free_run(0.0)
    assert angles[-1] > 2.0 and np.ptp(angles[-2000:]) < 3.0
    np.testing.assert_array_equal(est.bias, np.zeros(3))


def test_bias_estimate_is_kept_within_its_bound_and_bad_settings_are_refused():
    p = EstimatorParams(bias_gain=(GAIN,) * 3, bias_max=0.012)
    t, rs, rates = trajectory(0.01, 60.0)
    acc, mag = body_directions(p, rs)
    est = VariationalEstimator(p)
    est.update_batch(steps_of(t, rates + BIAS, acc, mag))
    assert np.all(np.abs(est.bias) <= 0.012 + 1e-15) and np.abs(est.bias).max() == pytest.approx(0.012)
    for bad in ({"bias_gain": (-1.0, 0.0, 0.0)}, {"bias_max": 0.0}, {"gyro_delay_s": -1e-3},
                {"bias_vertical": float("nan")}):  # fmt: skip
        with pytest.raises(ConfigError):
            EstimatorParams(**bad)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- on a simulated phone
def phone_steps(
    rate, duration: float, spec: PhoneSpec, seed: int, acc_enu=None
) -> tuple[MergedSteps, Trajectory]:
    traj = Trajectory.from_rate(rate, duration, R0=so3.exp([0.3, -0.2, 0.5]), dt=2e-3, acc_enu=acc_enu)
    log = simulate(traj, spec, seed=seed)
    steps, _ = merge(log.streams, MergePolicy(driver=SensorKind.GYR))
    return steps.rows(first_full_step(steps)), traj


def gyro_bias_of(steps: MergedSteps, traj: Trajectory) -> np.ndarray:
    """The simulated gyro's bias: its mean reading less the true rate."""
    return np.mean(steps.gyr - traj.sample(steps.t)[1], axis=0)


def errors(steps: MergedSteps, traj, quats) -> AttitudeErrors:
    r_true, _, _ = traj.sample(steps.t)
    return AttitudeErrors.from_quats(quats, so3.matrix_to_quat(r_true))


def biased_phone(bias: float) -> PhoneSpec:
    base = PhoneSpec.nexus5()
    return dataclasses.replace(base, gyr=dataclasses.replace(base.gyr, bias=bias))


def still(t: float) -> np.ndarray:
    return np.zeros(3)


def test_at_rest_the_bias_is_measured_within_seconds():
    """A phone lying still with a 1 °/s gyro bias and Nexus-5 noise, no still window given: rest is
    detected after ``rest_min_s`` and b̂ reaches the bias to a few 1e-4 rad/s within 10 s; without rest
    detection (the torque law alone) it is still far off then."""
    steps, traj = phone_steps(still, 12.0, biased_phone(0.02), seed=4)
    f = AttitudeFilter(FilterConfig.tuned(declination_deg=7.2))
    out = f.run(steps)
    rest = (out.flags & StepFlag.REST) != 0
    first = steps.t[np.argmax(rest)] - steps.t[0]
    assert 1.5 <= first < 2.5 and rest[steps.t - steps.t[0] > 3.0].all()
    true_bias = gyro_bias_of(steps, traj)
    assert np.linalg.norm(true_bias) > 0.015
    assert np.linalg.norm(f.gyro_bias - true_bias) < 5e-4
    slow = AttitudeFilter(FilterConfig.tuned(declination_deg=7.2, motion=None))
    slow.run(steps)
    assert np.linalg.norm(slow.gyro_bias - true_bias) > 5 * np.linalg.norm(f.gyro_bias - true_bias)


def test_rest_learning_can_be_switched_off_and_on_while_running():
    """``set_rest_learning(False)`` (the host, once its spacecraft moves under control): rest is still
    flagged but b̂ no longer follows the gyro there — only the torque law moves it, as with a zero
    ``rest_gain``; switched on again it learns as before. Live and batch paths alike (same kernel)."""
    steps, traj = phone_steps(still, 12.0, biased_phone(0.02), seed=4)
    true_bias = gyro_bias_of(steps, traj)
    half = len(steps) // 2
    off = AttitudeFilter(FilterConfig.tuned(declination_deg=7.2))
    off.set_rest_learning(False)
    out = off.run(steps.rows(0, half))
    assert ((out.flags & StepFlag.REST) != 0).any()
    motion = FilterConfig.tuned().motion
    assert motion is not None and motion.rest_gain > 0
    plain = AttitudeFilter(
        FilterConfig.tuned(declination_deg=7.2, motion=dataclasses.replace(motion, rest_gain=0.0))
    )
    plain.run(steps.rows(0, half))
    np.testing.assert_array_equal(off.gyro_bias, plain.gyro_bias)
    assert np.linalg.norm(off.gyro_bias - true_bias) > 0.5 * np.linalg.norm(true_bias)
    off.set_rest_learning(True)
    for i in range(half, len(steps)):
        off.step(steps[i])
    assert np.linalg.norm(off.gyro_bias - true_bias) < 0.1 * np.linalg.norm(true_bias)


def test_in_motion_the_bias_is_learnt_and_the_heading_holds():
    """The testbed's turning (no rest) with a 0.6 °/s gyro bias, 180 s: the online estimate takes most of
    the bias out, and the attitude error over the last minute is well below the filter's without it."""
    steps, traj = phone_steps(paper_testbed_rate, 180.0, biased_phone(0.01), seed=5)
    true_bias = gyro_bias_of(steps, traj)
    online = AttitudeFilter(FilterConfig.tuned(declination_deg=7.2))
    e_on = errors(steps, traj, online.run(steps).quat)
    p = FilterConfig.tuned().params
    fixed = FilterConfig.tuned(
        declination_deg=7.2, motion=None, params=dataclasses.replace(p, bias_gain=(0.0,) * 3)
    )
    e_off = errors(steps, traj, AttitudeFilter(fixed).run(steps).quat)
    last = steps.t - steps.t[0] > 120.0
    assert np.linalg.norm(online.gyro_bias - true_bias) < 0.5 * np.linalg.norm(true_bias)
    assert np.sqrt(np.mean(e_on.total[last] ** 2)) < 0.6 * np.sqrt(np.mean(e_off.total[last] ** 2))


def test_the_still_window_is_an_optional_initialiser():
    """Given the bias measured over a still window, the filter starts from it (and keeps it, the phone
    being at rest); given none it finds it itself."""
    steps, traj = phone_steps(still, 6.0, biased_phone(0.02), seed=6)
    true_bias = gyro_bias_of(steps, traj)
    given = AttitudeFilter(FilterConfig.tuned(gyro_bias=tuple(true_bias)))
    given.run(steps.rows(0, 10))
    assert np.linalg.norm(given.gyro_bias - true_bias) < 1e-4
    given.set_gyro_bias(true_bias + 1e-3)
    np.testing.assert_allclose(given.gyro_bias, true_bias + 1e-3)
    with pytest.raises(ConfigError):
        given.set_gyro_bias([np.nan, 0.0, 0.0])


# --------------------------------------------------------------------------- accelerometer trust
def test_the_accelerometer_is_trusted_when_calm_and_not_when_shaken():
    """The motion kernel against its reference, and what it says: turning slowly (gravity steady in the
    strapdown frame) keeps the cut-off scale at ``calm``; shaking drives it to ``dynamic``."""
    s = MotionSettings(calm=2.0, dynamic=0.25, acc_scale=1.0)
    mp, ms = pack_motion_params(s), mo.new_motion_state()
    ref = reference_chain.Motion(s)
    rng = np.random.default_rng(7)
    h = 0.005
    scales = []
    for i in range(4000):
        shaking = 1500 <= i < 2500
        acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.03, 3)
        if shaking:
            acc += 4.0 * np.array([np.sin(2 * np.pi * 3.0 * i * h), np.cos(2 * np.pi * 2.0 * i * h), 0.0])
        gyr = np.array([0.0, 0.0, 0.02]) + rng.normal(0.0, 2e-3, 3)
        rest = motion_step(mp, ms, h, *gyr, 0.0, 0.0, 0.0, *acc)
        assert bool(rest) == ref.step(h, gyr, np.zeros(3), acc)
        assert ms[mo.MS_ACC_CUT] == pytest.approx(ref.cut_scale, abs=1e-12)
        scales.append(ms[mo.MS_ACC_CUT])
    scales = np.array(scales)
    assert scales[1000:1500].min() > 1.9 and scales[1800:2500].max() < 0.5 and scales[3500:].min() > 1.9
    with pytest.raises(ConfigError, match="calm"):
        pack_motion_params(MotionSettings(calm=0.0))


def test_slow_turns_get_tight_inclination_and_shaking_does_not_pull_it():
    """A phone turning slowly, then shaken for 10 s with a one-sided push (4 m/s²·|sin| at 2 Hz: a mean
    horizontal acceleration, which any low-pass lets through in the end). The trust adapting between
    ``calm`` and ``dynamic`` tracks like the calm cut-off while calm — far tighter than the dynamic one —
    and is pulled far more slowly than the calm cut-off once shaken."""

    def push(t: float) -> np.ndarray:
        return (20.0 <= t < 30.0) * 4.0 * abs(np.sin(2 * np.pi * 2.0 * t)) * np.array([1.0, 0.3, 0.0])

    steps, traj = phone_steps(lambda t: np.array([0.0, 0.0, 0.1]), 40.0, PhoneSpec.nexus5(), 8, push)
    ms = MotionSettings(calm=2.0, dynamic=0.2, acc_scale=0.5)
    adaptive = FilterConfig.tuned(declination_deg=7.2, motion=ms)
    calm = dataclasses.replace(adaptive, motion=dataclasses.replace(ms, dynamic=2.0))
    dynamic = dataclasses.replace(adaptive, motion=dataclasses.replace(ms, calm=0.2))
    t = steps.t - steps.t[0]
    a, c, d = (
        errors(steps, traj, AttitudeFilter(x).run(steps).quat).inclination for x in (adaptive, calm, dynamic)
    )
    rms = lambda e, t0, t1: float(np.sqrt(np.mean(e[(t >= t0) & (t < t1)] ** 2)))  # noqa: E731
    assert rms(a, 5, 20) < 1.1 * rms(c, 5, 20) and rms(a, 5, 20) < 0.6 * rms(d, 5, 20)
    assert rms(a, 20, 25) < 0.6 * rms(c, 20, 25)


# --------------------------------------------------------------------------- 6-axis
def test_six_axis_mode_observes_inclination_and_ignores_the_field():
    """``magnetometer="none"``: started from gravity alone, the inclination converges as with the field;
    the heading is the gyro's integral — a disturbed field changes nothing."""
    steps, traj = phone_steps(paper_testbed_rate, 40.0, PhoneSpec.nexus5(), seed=9)
    six = FilterConfig.tuned(magnetometer="none")
    out = AttitudeFilter(six).run(steps)
    e = errors(steps, traj, out.quat)
    later = steps.t - steps.t[0] > 10.0
    nine = errors(steps, traj, AttitudeFilter(FilterConfig.tuned()).run(steps).quat)
    rms_six, rms_nine = (float(np.sqrt(np.mean(x.inclination[later] ** 2))) for x in (e, nine))
    assert rms_six < 1.5 and rms_six < 1.25 * rms_nine  # measured 1.20° against 1.36° with the field
    bent = dataclasses.replace(steps, mag=steps.mag * 3.0 + 20.0)
    np.testing.assert_array_equal(AttitudeFilter(six).run(bent).R, out.R)


def test_a_log_without_a_magnetometer_runs_through_the_same_filter():
    """Steps with the magnetometer stale throughout (a 6-axis log as the merger gives it): the tuned
    filter starts from gravity alone and keeps the inclination; nothing is NaN."""
    steps, traj = phone_steps(paper_testbed_rate, 30.0, PhoneSpec.nexus5(), seed=10)
    no_mag = dataclasses.replace(
        steps, mag=np.full_like(steps.mag, np.nan), flags=steps.flags | int(StepFlag.MAG_STALE)
    )
    out = AttitudeFilter(FilterConfig.tuned()).run(no_mag)
    assert np.all(np.isfinite(out.R))
    e = errors(no_mag, traj, out.quat)
    assert e.inclination[0] < 3.0 and np.sqrt(np.mean(e.inclination[steps.t - steps.t[0] > 10.0] ** 2)) < 1.5
