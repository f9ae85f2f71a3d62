"""The paper's variational estimator: its check figure, a direct transcription, convergence order,
structure preservation, parameter checks and how it reports trouble."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import fsolve

from hil import so3
from hil.estimation import variational as est_mod
from hil.estimation.estimator import VariationalEstimator
from hil.estimation.params import PAPER_OMEGA0, EstimatorParams, paper_initial_attitude, phi_log, wahba
from hil.estimation.sensors import MergedSteps, StepFlag
from protocol.errors import ConfigError, ConvergenceError


def truth_rate(t: float) -> np.ndarray:
    """A smooth body rate of 0.1–0.3 rad/s, like a phone turning on the testbed."""
    return np.array([0.1 * np.sin(0.3 * t) + 0.1, 0.2 * np.cos(0.2 * t), 0.15 * np.sin(0.1 * t + 1.0)])


def trajectory(h: float, duration: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times, true attitudes (body → ENU) and rates, integrated with the midpoint rule at step h."""
    n = int(round(duration / h)) + 1
    rs = np.empty((n, 3, 3))
    rs[0] = so3.exp([0.3, -0.2, 0.5])
    for i in range(1, n):
        rs[i] = rs[i - 1] @ so3.exp(h * truth_rate((i - 0.5) * h))
    t = np.arange(n) * h
    return t, rs, np.array([truth_rate(x) for x in t])


def body_directions(params: EstimatorParams, rs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free accelerometer and magnetometer directions u = Rᵀ e."""
    return np.einsum("nji,j->ni", rs, params.E[:, 0]), np.einsum("nji,j->ni", rs, params.E[:, 1])


def run_paper_case(h: float = 0.01, duration: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    p = EstimatorParams.paper()
    t, rs, rates = trajectory(h, duration)
    acc, mag = body_directions(p, rs)
    est = VariationalEstimator(p, R0=paper_initial_attitude(rs[0]), omega_err0=PAPER_OMEGA0)
    out = est.update_batch(steps_of(t, rates, acc, mag))
    angles = np.degrees([so3.angle_between(a, b) for a, b in zip(rs, out.R, strict=True)])
    return t, angles


def steps_of(t, gyr, acc, mag) -> MergedSteps:
    n = len(t)
    return MergedSteps(
        np.asarray(t, float), gyr, acc, mag, np.zeros((n, 3)), np.ones((n, 3), bool), np.zeros(n, np.int64)
    )


def test_paper_check_figure_127_to_15_to_1_5_degrees():
    """DESIGN.md's check of a direct transcription: 127° → ≈15° at 10 s → ≈1.5° at 20 s."""
    t, angles = run_paper_case()
    assert angles[0] == pytest.approx(126.8, abs=0.5)
    assert 12.0 < angles[t.searchsorted(10.0)] < 18.0
    assert 1.0 < angles[t.searchsorted(20.0)] < 2.0
    assert np.all(np.diff(angles[t > 1.0]) < 1e-6)  # monotone once the first transient is over


def test_flipped_sign_of_S_L_diverges(monkeypatch):
    """The same case with the potential's torque negated goes to 180° (so the check above can fail)."""
    flip_sign_of_S_L(monkeypatch)
    _, angles = run_paper_case()
    assert angles[-1] > 170.0


def flip_sign_of_S_L(monkeypatch):
    """Negate the compiled kernel's tables of L = E W Uᵀ: S_L(R̂) = vex(LᵀR̂ − R̂ᵀL) is linear in L, so the
    potential's torque Φ'(U⁰) S_L flips sign (Φ' is constant for the paper's Φ(x) = x)."""
    original = est_mod.pack_params

    def flipped(p):
        ep = original(p)
        ep[est_mod.P_MTAB : est_mod.P_MTAB + 8 * 9] *= -1.0
        return ep

    monkeypatch.setattr(est_mod, "pack_params", flipped)


# --------------------------------------------------------------------------- a direct transcription
def transcription(p: EstimatorParams, r0, w0, t, gyr, acc, mag):
    """The paper's equations verbatim on numpy arrays, the implicit step by scipy's fsolve (numerical
    Jacobian): an independent reference for the float kernel."""
    e, wgt, m, d = p.E, p.W, p.m, p.D

    def u_of(a, b):
        u1, u2 = a / np.linalg.norm(a), b / np.linalg.norm(b)
        c = np.cross(u1, u2)
        return np.column_stack([u1, u2, c / np.linalg.norm(c)])

    def torque(r, u):
        big_l = e @ wgt @ u.T
        diff = e - r @ u
        u0 = 0.5 * np.trace(diff.T @ diff @ wgt)
        return p.phi.derivative(u0) * so3.vee(big_l.T @ r - r.T @ big_l)  # Φ'(U⁰) S_L

    r, w = np.array(r0, float), np.array(w0, float)
    rs, ws = [r], [w]
    for i in range(len(t) - 1):
        h = t[i + 1] - t[i]
        u_i, u_n = u_of(acc[i], mag[i]), u_of(acc[i + 1], mag[i + 1])
        s_i = torque(r, u_i)
        om_hat_i = gyr[i] - w
        w_half = np.linalg.solve(
            m * np.eye(3) + h / 2 * d, so3.exp(-h / 2 * om_hat_i) @ (m * w) + h / 2 * s_i
        )
        r = r @ so3.exp(h * ((gyr[i] + gyr[i + 1]) / 2 - w_half))
        s_n = torque(r, u_n)
        rhs = (m * np.eye(3) - h / 2 * d) @ w_half + h / 2 * s_n
        w = fsolve(
            lambda x, g=gyr[i + 1], c=rhs, hh=h / 2: m * x - so3.exp(-hh * (g - x)) @ c, w_half, xtol=1e-14
        )
        rs.append(r)
        ws.append(w)
    return np.array(rs), np.array(ws)


def test_kernel_matches_a_direct_transcription_with_full_D_and_log_potential():
    d = np.array([[12.0, 2.0, -1.0], [2.0, 13.0, 0.5], [-1.0, 0.5, 14.0]])
    p = EstimatorParams(D=d, phi=phi_log(2.0))
    t, rs, rates = trajectory(0.02, 4.0)
    acc, mag = body_directions(p, rs)
    rng = np.random.default_rng(3)
    acc = acc + 0.05 * rng.normal(size=acc.shape)
    gyr = rates + 0.02 * rng.normal(size=rates.shape)
    r0 = paper_initial_attitude(rs[0])
    ref_r, ref_w = transcription(p, r0, PAPER_OMEGA0, t, gyr, acc, mag)
    out = VariationalEstimator(p, r0, PAPER_OMEGA0).update_batch(steps_of(t, gyr, acc, mag))
    np.testing.assert_allclose(out.R, ref_r, atol=1e-10)
    np.testing.assert_allclose(out.omega_err, ref_w, atol=1e-10)
    np.testing.assert_allclose(out.omega, gyr - ref_w, atol=1e-10)


def test_per_sample_update_and_batch_agree_to_rounding():
    p = EstimatorParams.paper()
    t, rs, rates = trajectory(0.01, 3.0)
    acc, mag = body_directions(p, rs)
    acc[50:60] = np.nan  # a drop-out: both paths must treat it the same
    one = VariationalEstimator(p, paper_initial_attitude(rs[0]), PAPER_OMEGA0)
    singles = [one.update(0.01, g, a, m) for g, a, m in zip(rates, acc, mag, strict=True)]
    batch = VariationalEstimator(p, paper_initial_attitude(rs[0]), PAPER_OMEGA0).update_batch(
        steps_of(t, rates, acc, mag)
    )
    np.testing.assert_allclose(np.array([s.R for s in singles]), batch.R, atol=1e-14)
    np.testing.assert_allclose(np.array([s.omega for s in singles]), batch.omega, atol=1e-14)
    assert [int(s.flags) for s in singles] == batch.flags.tolist()
    assert one.stats.no_direction == 0  # the magnetometer alone still gives a direction


# --------------------------------------------------------------------------- convergence order
def test_second_order_convergence_as_h_shrinks():
    """The discrete filter converges to its continuous-time limit at order 2: halving h quarters the
    error at a fixed time, measured against a fine-step (h/32) reference with smooth, exact inputs."""
    p = EstimatorParams.paper()
    duration = 2.0

    def final_state(h: float) -> tuple[np.ndarray, np.ndarray]:
        t = np.arange(int(round(duration / h)) + 1) * h
        # inputs are smooth functions of time, sampled at each grid (not the integrated truth)
        rates = np.array([truth_rate(x) for x in t])
        acc = np.array([[np.sin(0.7 * x), 0.3 * np.cos(x), 1.0] for x in t])
        mag = np.array([[0.2, np.cos(0.5 * x), -0.6 + 0.1 * np.sin(x)] for x in t])
        out = VariationalEstimator(p, paper_initial_attitude(np.eye(3)), PAPER_OMEGA0).update_batch(
            steps_of(t, rates, acc, mag)
        )
        return out.R[-1], out.omega_err[-1]

    ref_r, ref_w = final_state(0.04 / 32)
    errors = []
    for h in (0.04, 0.02, 0.01):
        r, w = final_state(h)
        errors.append(so3.angle_between(r, ref_r) + np.linalg.norm(w - ref_w))
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(3.5 < q < 4.6 for q in ratios), (errors, ratios)


# --------------------------------------------------------------------------- structure preservation
@pytest.mark.slow
def test_attitude_stays_a_rotation_over_a_million_steps():
    """10⁶ real estimator steps (100 Hz, ~2.8 h of a phone turning at up to ~2 rad/s with noisy
    measurements): ‖R̂ᵀR̂ − I‖ stays below 1e-12 (it stays at rounding level throughout)."""
    n = 1_000_000
    rng = np.random.default_rng(7)
    t = np.arange(n) * 0.01
    gyr = np.column_stack([np.sin(0.5 * t), 2 * np.cos(0.13 * t), 0.7 * np.sin(0.011 * t)])
    gyr += 0.01 * rng.normal(size=gyr.shape)
    acc = np.array([0.0, 0.0, 9.81]) + 0.3 * rng.normal(size=(n, 3))
    mag = np.array([0.0, 20.0, -40.0]) + 1.0 * rng.normal(size=(n, 3))
    est = VariationalEstimator(EstimatorParams.paper())
    out = est.update_batch(steps_of(t, gyr, acc, mag))
    worst = max(so3.orthonormality_error(r) for r in out.R[:: n // 1000])
    assert so3.orthonormality_error(out.R[-1]) < 1e-12
    assert worst < 1e-12
    assert est.stats.newton_failures == 0


# --------------------------------------------------------------------------- parameters
def _w_giving(ewe: np.ndarray) -> np.ndarray:
    """The symmetric W with E W Eᵀ = ewe for the paper's E."""
    e_inv = np.linalg.inv(EstimatorParams.paper().E)
    w = e_inv @ ewe @ e_inv.T
    return (w + w.T) / 2


@pytest.mark.parametrize(
    ("w", "message"),
    [
        (_w_giving(np.diag([1.0, 1.0, 2.0])), "distinct eigenvalues"),
        (np.diag([1.0, -3.0, 2.0]), "positive definite"),
        (np.array([[3.19, 1.51, 0], [1.0, 3.19, 0], [0, 0, 2]]), "symmetric"),
        (np.eye(2), "3x3"),
        (np.full((3, 3), np.nan), "finite"),
    ],
)
def test_bad_W_is_a_config_error_naming_W(w, message):
    with pytest.raises(ConfigError, match=message) as info:
        EstimatorParams(W=w)
    assert "W" in info.value.where


def test_orthonormal_E_with_equal_weights_is_rejected_but_paper_E_accepted():
    e = np.eye(3)
    with pytest.raises(ConfigError, match="distinct"):
        EstimatorParams(E=e, W=np.diag([1.0, 1.0, 2.0]))
    EstimatorParams(E=e, W=np.diag([1.0, 2.0, 3.0]))
    EstimatorParams.paper()


@pytest.mark.parametrize(
    ("kwargs", "where"),
    [
        ({"m": 0.0}, "m"),
        ({"D": -np.eye(3)}, "D"),
        ({"E": np.array([[0, 0.1, 0], [0, 0.9, 0.1], [1, -0.4, 0]])}, "E"),
        ({"newton_max_iter": 0}, "newton_max_iter"),
        ({"on_newton_failure": "ignore"}, "on_newton_failure"),
    ],
)
def test_other_bad_parameters_are_config_errors(kwargs, where):
    with pytest.raises(ConfigError) as info:
        EstimatorParams(**kwargs)
    assert where in info.value.where


# --------------------------------------------------------------------------- reporting trouble
def test_newton_failure_is_flagged_and_counted_or_raised_by_policy():
    p = EstimatorParams(newton_max_iter=1, newton_tol=1e-300)
    est = VariationalEstimator(p)
    est.update(0.01, [0.1, 0.2, 0.3], [0, 0, 9.8], [0, 20, -40])
    out = est.update(0.01, [0.5, 0.2, 0.3], [0, 0.5, 9.8], [0, 20, -40])
    assert out.flags & StepFlag.NEWTON_FAILED
    assert est.stats.newton_failures == 1
    assert so3.is_rotation(out.R, 1e-12) and np.all(np.isfinite(out.omega))
    strict = VariationalEstimator(
        EstimatorParams(newton_max_iter=1, newton_tol=1e-300, on_newton_failure="raise")
    )
    strict.update(0.01, [0.1, 0.2, 0.3], [0, 0, 9.8], [0, 20, -40])
    with pytest.raises(ConvergenceError, match="Newton"):
        strict.update(0.01, [0.5, 0.2, 0.3], [0, 0.5, 9.8], [0, 20, -40])


def test_newton_converges_in_two_updates_at_phone_rates():
    p = EstimatorParams.paper()
    t, rs, rates = trajectory(0.005, 2.0)
    acc, mag = body_directions(p, rs)
    est = VariationalEstimator(p, paper_initial_attitude(rs[0]), PAPER_OMEGA0)
    out = est.update_batch(steps_of(t, rates * 10, acc, mag))  # up to ~3 rad/s
    assert out.iterations[1:].max() <= 3
    assert est.stats.newton_failures == 0


def test_unusable_inputs_never_crash_and_are_flagged():
    est = VariationalEstimator()
    est.update(0.01, [0.0, 0.0, 0.1], [0, 0, 9.8], [0, 20, -40])
    gyro_gone = est.update(0.01, None, [0, 0, 9.8], [0, 20, -40])
    assert gyro_gone.flags & StepFlag.GYR_STALE
    nan_acc = est.update(0.01, [0.0, 0.0, 0.1], [np.nan, 0, 9.8], [0, 20, -40])
    nothing = est.update(0.01, [0.0, 0.0, 0.1], None, [np.inf, 0, 0])
    zero_acc = est.update(0.01, [0.0, 0.0, 0.1], [0, 0, 0], [0, 20, -40])
    parallel = est.update(0.01, [0.0, 0.0, 0.1], [0, 0, 9.8], [0, 0, -40])
    assert parallel.flags & StepFlag.DEGENERATE
    for out in (nan_acc, nothing, zero_acc, parallel):
        assert so3.is_rotation(out.R, 1e-12) and np.all(np.isfinite(out.omega))
    assert est.stats.no_direction == 1 and est.stats.gyro_missing == 1 and est.stats.degenerate == 1
    with pytest.raises(ValueError, match="dt"):
        est.update(0.0, [0, 0, 0], None, None)


def test_every_form_of_a_sample_gives_the_same_step_and_a_bad_one_a_named_error():
    """update's fast path (lists and tuples of three, converted by the compiled call itself) and its
    checked path (arrays, None) give identical numbers; ints are numbers; a wrong length or an item that
    is not a number is an error naming update's inputs, and the state is left as it was."""
    rng = np.random.default_rng(5)
    samples = [
        (rng.normal(0, 0.3, 3), rng.normal([0, 0, 9.8], 0.5), rng.normal([0, 20, -40], 2)) for _ in range(50)
    ]
    forms = {
        "lists": lambda v: v.tolist(),
        "tuples": lambda v: tuple(v.tolist()),
        "arrays": lambda v: v,
        "column arrays": lambda v: v.reshape(3, 1),
        "lists of numpy floats": lambda v: list(v),
    }
    outs = {}
    for name, form in forms.items():
        est = VariationalEstimator()
        outs[name] = np.array([est.update(0.01, *(form(v) for v in sample)).R for sample in samples])
    for name, R in outs.items():
        np.testing.assert_array_equal(R, outs["lists"], err_msg=name)
    est = VariationalEstimator()
    assert np.array_equal(est.update(1, [0, 0, 1], [0, 0, 10], [0, 20, -40]).R, np.eye(3))  # ints
    before = est.state
    with pytest.raises(TypeError, match="update: dt, gyr, acc and mag must be numbers"):
        est.update(0.01, [0.0, "fast", 0.1], [0, 0, 9.8], [0, 20, -40])
    with pytest.raises(TypeError, match="update: dt, gyr, acc and mag must be numbers"):
        est.update(0.01, (0.0, None, 0.1), [0, 0, 9.8], [0, 20, -40])
    with pytest.raises(ValueError):
        est.update(0.01, [0.0, 0.1], [0, 0, 9.8], [0, 20, -40])
    after = est.state
    assert after.t == before.t and np.array_equal(after.R, before.R) and est.stats.steps == 1


def test_an_estimate_keeps_its_own_values_read_only_whatever_the_estimator_does_next():
    """The live path's Estimate holds the state's head as bytes: its arrays are the state's values at its
    sample (not a view of the state the next update overwrites), they cannot be written through, its floats
    are its arrays' values, and one built by the constructor equals one the estimator returned."""
    from hil.estimation.estimator import Estimate

    rng = np.random.default_rng(11)
    est = VariationalEstimator()
    kept = []
    for _ in range(20):
        e = est.update(0.01, rng.normal(0, 0.3, 3).tolist(), [0.0, 0.0, 9.8], [0.0, 20.0, -40.0])
        s = est.state
        kept.append((e, s.R.copy(), s.omega_err.copy()))
    for e, R, omega_err in kept:  # every estimate still holds its own sample's values
        np.testing.assert_array_equal(e.R, R)
        np.testing.assert_array_equal(e.omega_err, omega_err)
        assert e.R.shape == (3, 3) and e.omega.shape == (3,) and e.omega_err.shape == (3,)
        for array in (e.R, e.omega, e.omega_err):
            with pytest.raises(ValueError, match="read-only"):
                array[0] = 1.0
        R9, w = e.floats()
        assert list(R9) == e.R.ravel().tolist() and list(w) == e.omega.tolist()
        assert all(type(v) is float for v in (*R9, *w))
        rebuilt = Estimate(e.t, e.R, e.omega, e.omega_err, e.flags, e.iterations)
        assert rebuilt == e and rebuilt.omega_err.tolist() == e.omega_err.tolist()
    assert len({e.t for e, _, _ in kept}) == len(kept)


def test_gyro_only_propagation_integrates_the_rate():
    est = VariationalEstimator()  # ω0 = 0 and no directions: R̂ follows the gyro exactly
    rate = np.array([0.0, 0.0, 0.5])
    for _ in range(101):
        out = est.update(0.01, rate)
    np.testing.assert_allclose(out.R, so3.exp(rate * 1.0), atol=1e-12)
    np.testing.assert_allclose(out.omega, rate, atol=1e-15)


def test_long_step_is_split_into_substeps_with_interpolated_gyro():
    p = EstimatorParams(max_step_s=0.05)
    a, b = VariationalEstimator(p), VariationalEstimator(p)
    acc, mag = [0.1, 0.2, 9.8], [0, 20, -40]
    g0, g1 = np.array([0.1, 0.0, 0.2]), np.array([0.3, -0.1, 0.2])
    a.update(0.0, g0, acc, mag)
    long = a.update(0.2, g1, acc, mag)
    assert long.flags & StepFlag.SUBSTEPPED and a.stats.substeps == 3
    b.update(0.0, g0, acc, mag)
    for f in (0.25, 0.5, 0.75, 1.0):
        short = b.update(0.05, g0 + f * (g1 - g0), acc, mag)
    np.testing.assert_allclose(long.R, short.R, atol=1e-14)
    np.testing.assert_allclose(long.omega_err, short.omega_err, atol=1e-14)


def test_snapshot_and_restore_resume_exactly():
    p = EstimatorParams.paper()
    t, rs, rates = trajectory(0.01, 1.0)
    acc, mag = body_directions(p, rs)
    est = VariationalEstimator(p, paper_initial_attitude(rs[0]), PAPER_OMEGA0)
    est.update_batch(steps_of(t[:50], rates[:50], acc[:50], mag[:50]))
    snap = est.state
    first = est.update_batch(steps_of(t[50:], rates[50:], acc[50:], mag[50:]))
    est.restore(snap)
    again = est.update_batch(steps_of(t[50:], rates[50:], acc[50:], mag[50:]))
    np.testing.assert_array_equal(first.R, again.R)
    np.testing.assert_array_equal(first.t, again.t)


def test_wahba_recovers_the_attitude_from_exact_directions():
    p = EstimatorParams.paper()
    r = so3.exp([0.4, -1.2, 2.0])
    acc, mag = r.T @ p.E[:, 0] * 9.81, r.T @ p.E[:, 1] * 45.0
    np.testing.assert_allclose(wahba(p, acc, mag), r, atol=1e-12)
