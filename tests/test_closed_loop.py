"""Acceptance in lockstep simulation at 1U scale: the closed loop (plant at 1 ms, controller, steering and
setpoints at 50 Hz, servo drives) slews 90° rest-to-rest and slews through a CMG singularity, first with the
true attitude plus phone-grade noise, then with the paper's estimator fed by a simulated phone in the loop.
Each test prints its figures (``pytest -s``)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hil import so3
from hil.simulation.closed_loop import (
    ClosedLoop,
    EstimatorInTheLoop,
    LoopConfig,
    SlewScenario,
    TruthWithNoise,
    slew_90deg,
    slew_through_singularity,
)
from hil.simulation.phone import PhoneSpec
from hil.vscmg import cubesat_1u
from protocol.errors import ConfigError

PARAMS = cubesat_1u()


def _quick(scenario: SlewScenario, duration_s: float) -> SlewScenario:
    """The scenario with brisker limits (0.2 rad/s, 0.04 rad/s²) and a shorter run, to keep CI fast."""
    return dataclasses.replace(scenario, max_rate=0.2, max_accel=0.04, duration_s=duration_s)


def _report(name, log):
    s = log.summary()
    print(
        f"\n{name}: settle {s['settle_time_s']:.2f} s, final error {s['final_error_deg']:.3f} deg, "
        f"peak gimbal rate {s['peak_gimbal_rate']:.3f} rad/s, min delta {s['min_delta']:.4f}, "
        f"slew end {log.slew_end_s:.1f} s"
    )
    return s


def _check_acceptance(log, s):
    assert s["settle_time_s"] <= 30.0
    assert s["final_error_deg"] <= 0.5
    assert np.all(log.error_deg[log.t >= s["settle_time_s"]] <= 0.5)
    assert s["peak_gimbal_rate"] <= PARAMS.limits.max_gimbal_rate
    assert np.all(np.isfinite(log.gimbal_rate)) and np.all(np.isfinite(log.rotor_speed))


@pytest.fixture(scope="module")
def truth_runs():
    """Both truth + noise scenarios, stepped together on the plant's batch axis (one run's cost)."""
    scenarios = [_quick(slew_90deg(), 18.0), _quick(slew_through_singularity(), 14.0)]
    return ClosedLoop(PARAMS).run_batch(scenarios, [TruthWithNoise(seed=3), TruthWithNoise(seed=4)])


def test_90_degree_slew_settles_with_truth_and_phone_grade_noise(truth_runs):
    log = truth_runs[0]
    s = _report("90 deg, truth + noise", log)
    _check_acceptance(log, s)
    assert log.t[-1] == pytest.approx(18.0 - 0.02)
    assert log.error_deg[0] == pytest.approx(90.0, abs=0.01)
    assert np.max(log.tracking_deg) < 2.0  # it followed the reference, not just ended near the target
    assert s["min_delta"] > 0.5  # a healthy CMG path: no wheel mode needed
    assert np.max(np.abs(log.torque_shortfall)) < 1e-12  # steering always delivered the requested torque


def test_slew_through_a_cmg_singularity_completes_without_blow_up(truth_runs):
    log = truth_runs[1]
    s = _report("60 deg about the singular direction, truth + noise", log)
    _check_acceptance(log, s)
    assert log.t[-1] == pytest.approx(14.0 - 0.02)
    assert s["min_delta"] < 0.05  # it did start next to the singularity (δ ≈ 1.19 far from it)
    assert log.delta[-1] > 10 * s["min_delta"]  # null motion and the manoeuvre moved the gimbals away
    speeds = log.rotor_speed
    assert np.all(speeds >= PARAMS.limits.min_rotor_speed) and np.all(speeds <= PARAMS.limits.max_rotor_speed)


def test_estimator_in_the_loop_90_degree_slew():
    """The paper's estimator (hil.estimation.estimator, its parameters and 1 rad/s pre-filter) on a
    simulated Nexus-5
    fixed to the body: gyroscope, accelerometer and magnetometer at their own rates with jitter and white
    noise (sensor biases are left out here: the residual magnetometer and accelerometer biases of
    PhoneSpec.nexus5 alone shift the estimate by ~1°, see docs/dynamics.md)."""
    base = PhoneSpec.nexus5()
    spec = dataclasses.replace(
        base, **{k: dataclasses.replace(getattr(base, k), bias=0.0) for k in ("gyr", "acc", "mag")}
    )
    source = EstimatorInTheLoop(spec=spec, seed=5)
    log = ClosedLoop(PARAMS).run(_quick(slew_90deg(), 22.0), source)
    s = _report("90 deg, estimator in the loop", log)
    _check_acceptance(log, s)
    assert source.steps > 4000  # ~200 Hz phone steps over warm-up and slew went through the estimator
    assert np.max(log.estimate_error_deg) > 0.5  # the loop ran on the estimate, not on the truth


def test_the_estimator_gets_the_still_window_gyro_bias_as_on_the_host():
    """As the host does, the raw gyro samples of the warm-up's still second half are averaged and handed
    to the estimator, which removes the phone gyro's bias (here ~5·10⁻³ rad/s, 0.3°/s) from then on. The
    same estimator behind a source that cannot calibrate itself (the rate bias is then only taken off the
    controller's rate) keeps a drifting attitude. A 5 s hold, both in one batch."""
    from hil.estimation.sensors import SensorKind

    class Uncalibrated:  # the same estimator, without begin/end_gyro_bias
        def __init__(self, inner):
            self.inner = inner
            self.start, self.observe, self.measure = inner.start, inner.observe, inner.measure

    base = PhoneSpec.nexus5()
    spec = dataclasses.replace(
        base, acc=dataclasses.replace(base.acc, bias=0.0), mag=dataclasses.replace(base.mag, bias=0.0)
    )
    calibrated, raw = EstimatorInTheLoop(spec=spec, seed=9), EstimatorInTheLoop(spec=spec, seed=9)
    hold = SlewScenario("hold", np.eye(3), np.eye(3), 5.0)
    logs = ClosedLoop(PARAMS).run_batch([hold, hold], [calibrated, Uncalibrated(raw)])
    true_bias = calibrated.phone.bias[SensorKind.GYR]
    assert np.linalg.norm(true_bias) > 3e-3 and raw.gyro_bias is None
    n = 0.5 * LoopConfig().warmup_s * spec.gyr.rate_hz  # samples in the window
    np.testing.assert_allclose(calibrated.gyro_bias, true_bias, atol=4 * spec.gyr.noise / math.sqrt(n))
    assert logs[0].estimate_error_deg[-1] < 0.3 and logs[0].error_deg[-1] < 0.3
    assert logs[1].estimate_error_deg[-1] > 1.0


def test_harness_refuses_bad_rates():
    with pytest.raises(ConfigError, match="plant_step_s"):
        LoopConfig(plant_step_s=2e-3)
    with pytest.raises(ConfigError, match="whole number"):
        LoopConfig(control_rate_hz=30.0, plant_step_s=7e-4)
    with pytest.raises(ConfigError, match="one attitude source per scenario"):
        ClosedLoop(PARAMS).run_batch([slew_90deg()], [])
    with pytest.raises(ConfigError, match="pulse frame rate"):
        ClosedLoop(PARAMS, LoopConfig(control_rate_hz=100.0, frame_rate_hz=50.0)).run(
            SlewScenario("x", np.eye(3), so3.exp([0, 0, math.radians(5)]), 0.1), TruthWithNoise()
        )


# --------------------------------------------------------------------------- dispersed plant, link faults
@pytest.fixture(scope="module")
def fault_runs():
    """One batch: nominal; a 0.1 s outage (shorter than the 0.25 s link timeout); a 1 s outage (failsafe);
    a spacecraft 15 % heavier in inertia than the controller believes. 20° slews of 9 s, truth + noise."""
    slew = SlewScenario("20deg", np.eye(3), so3.exp([0.0, 0.0, math.radians(20.0)]), 9.0, 0.2, 0.04)
    heavy = dataclasses.replace(PARAMS, bus_inertia=tuple(map(tuple, 1.15 * np.asarray(PARAMS.bus_inertia))))
    logs = ClosedLoop(PARAMS).run_batch(
        [slew] * 4,
        [TruthWithNoise(seed=7) for _ in range(4)],
        spacecraft=[PARAMS, PARAMS, PARAMS, heavy],
        link_outages=[(), [(1.0, 0.1)], [(1.0, 1.0)], ()],
    )
    return dict(zip(("nominal", "blip", "outage", "heavy"), logs, strict=True))


def test_a_link_blip_shorter_than_the_timeout_holds_the_last_setpoints(fault_runs):
    nominal, blip = fault_runs["nominal"], fault_runs["blip"]
    assert blip.failsafe_events == 0 and not blip.failsafe.any()
    lost = ~blip.link_up
    assert lost.sum() == 5 and blip.t[lost][0] == pytest.approx(1.0)  # five 20 ms ticks
    before = nominal.t < 1.0
    np.testing.assert_array_equal(blip.error_deg[before], nominal.error_deg[before])  # same run until then
    assert not np.array_equal(blip.error_deg, nominal.error_deg)  # the held setpoints did change the motion
    assert blip.settle_time(0.5) <= 7.0


def test_a_long_outage_trips_the_board_failsafe_gimbals_hold_and_rotors_coast(fault_runs):
    log, cfg = fault_runs["outage"], LoopConfig()
    assert log.failsafe_events == 1 and fault_runs["nominal"].failsafe_events == 0
    on = np.nonzero(log.failsafe)[0]
    # the watchdog fires 0.25 s after the last frame (the 0.98 s tick), seen at the next tick
    assert log.t[on[0]] == pytest.approx(0.98 + cfg.link_timeout_s, abs=0.021)
    # link back at 2.0 s: re-armed at that tick, setpoints again from the next
    assert log.t[on[-1]] == pytest.approx(2.0)
    assert np.all(log.failsafe[on[0] : on[-1] + 1])
    settled = on[5:]  # after the servo time constants
    assert np.max(np.abs(log.gimbal_rate[settled])) < 1e-3  # gimbals held
    w = log.rotor_speed[settled]
    span = log.t[settled[-1]] - log.t[settled[0]]
    np.testing.assert_allclose(w[-1] / w[0], math.exp(-span / cfg.esc_coast_time_constant_s), rtol=0.02)
    assert np.all(np.diff(w, axis=0) < 0)  # coasting down all the way, no throttle
    # the outage cost tracking; after re-arming the loop wins it back
    assert np.max(log.tracking_deg) > 1.0 > np.max(fault_runs["nominal"].tracking_deg)
    assert log.tracking_deg[-1] < 0.2 * np.max(log.tracking_deg) and log.error_deg[-1] < 1.0


def test_a_dispersed_plant_under_the_nominal_controller(fault_runs):
    nominal, heavy = fault_runs["nominal"], fault_runs["heavy"]
    assert not np.allclose(heavy.error_deg, nominal.error_deg)  # a different plant, same commands law
    assert heavy.settle_time(0.5) <= 7.0 and nominal.settle_time(0.5) <= 7.0
    # a per-run spacecraft equal to the nominal one is exactly the nominal run
    alone = ClosedLoop(PARAMS).run(
        dataclasses.replace(slew_90deg(), duration_s=0.5), TruthWithNoise(seed=7), spacecraft=PARAMS
    )
    shared = ClosedLoop(PARAMS).run(dataclasses.replace(slew_90deg(), duration_s=0.5), TruthWithNoise(seed=7))
    np.testing.assert_array_equal(alone.error_deg, shared.error_deg)


def test_bad_link_outages_and_per_run_lists_are_refused():
    loop, slew = ClosedLoop(PARAMS), dataclasses.replace(slew_90deg(), duration_s=0.1)
    with pytest.raises(ConfigError, match=r"link_outages\[0\]\[0\]"):
        loop.run(slew, TruthWithNoise(), link_outages=[(-1.0, 0.5)])
    with pytest.raises(ConfigError, match=r"link_outages\[0\]\[1\]"):
        loop.run(slew, TruthWithNoise(), link_outages=[(1.0, 0.5), (2.0,)])
    with pytest.raises(ConfigError, match="spacecraft"):
        loop.run_batch([slew], [TruthWithNoise()], spacecraft=[PARAMS, PARAMS])
    with pytest.raises(ConfigError, match="link_timeout_s"):
        LoopConfig(link_timeout_s=0.01)
