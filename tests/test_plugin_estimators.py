"""A user's estimator that misbehaves mid-run — returns NaN, a matrix that is no rotation, something that is
not an Estimate, or raises its own exception; a batch of the wrong length or with NaN rows; writes into the
steps it is given — ends ``hil run`` and ``hil replay`` with a PluginError naming it and the step: the run
says error (never completed), its board is left disarmed, no traceback. Before, a NaN estimate surfaced as
"ActuatorSetpoint.units[0].gimbal = nan is out of range", a scaled R flew to "completed", an exception or
a wrong type was a raw traceback, and a replay scored half its rows and said nothing."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from plugin_support import Delegating, estimators_in_a_module

from hil.cli import main
from hil.estimation.checked import ORTHONORMAL_TOL, RATE_LIMIT, CheckedEstimator
from hil.estimation.estimator import Estimate, EstimateBatch
from hil.estimation.registry import EstimatorChoice, register_estimator
from hil.estimation.sensors import MergedStep, StepFlag
from hil.estimation.variational_kind import VARIATIONAL
from hil.logs.replay import ReplayOptions, replay
from hil.plugins import PluginError
from protocol.errors import ConfigError, HilError

MODULE = "misbehaving_estimators_for_test"
LOG = Path(__file__).resolve().parents[1] / "fixtures" / "logs" / "simulated_testbed_4s.csv"


class Faulty(Delegating):
    """The variational estimator, until step ``after``: then what ``mode`` says."""

    def __init__(self, inner, mode: str, after: int) -> None:
        super().__init__(inner)
        self.mode, self.after, self.n = mode, after, 0

    def step(self, s):
        self.n += 1
        e = self.inner.step(s)
        if self.n < self.after:
            return e
        if self.mode == "nan":
            return Estimate(e.t, np.full((3, 3), np.nan), e.omega, e.omega_err, e.flags, e.iterations)
        if self.mode == "scaled":  # finite, but no rotation: the controller steered on it to "completed"
            return Estimate(e.t, 3.0 * e.R, e.omega, e.omega_err, e.flags, e.iterations)
        if self.mode == "raises":
            raise RuntimeError("my estimator blew up")
        if self.mode == "none":
            return None
        return e

    def run(self, steps, progress=None):
        if self.mode == "writes":
            steps.gyr[:] = 99.0  # the replay's own steps, scored and written afterwards
        b = self.inner.run(steps, progress)
        if self.mode == "nan_rows":
            R = b.R.copy()
            R[len(R) // 2 :] = np.nan
            return EstimateBatch(b.t, R, b.omega, b.omega_err, b.flags, b.iterations)
        if self.mode == "short":
            return EstimateBatch(
                b.t[:10], b.R[:10], b.omega[:10], b.omega_err[:10], b.flags[:10], b.iterations[:10]
            )
        return b


class FaultyKind:
    keys = frozenset({"preset"})

    def __init__(self, mode: str, after: int = 300) -> None:
        self.name, self.mode, self.after = f"faulty-{mode}", mode, after

    def check(self, settings, where):
        return VARIATIONAL.check(settings, where)

    def build(self, settings, site):
        return Faulty(VARIATIONAL.build(settings, site), self.mode, self.after)

    def describe(self, settings):
        return f"the variational estimator, faulty ({self.mode})"


MODES = ("nan", "scaled", "raises", "none", "nan_rows", "short", "writes")


@pytest.fixture(autouse=True)
def _registered() -> Iterator[None]:
    with estimators_in_a_module(
        MODULE, {f"faulty-{mode}": (mode.upper(), FaultyKind(mode)) for mode in MODES}
    ):
        yield


@pytest.mark.parametrize(
    ("mode", "said"),
    [
        ("nan", "returned a non-finite R"),
        ("scaled", "is not a rotation: R is not orthonormal"),
        ("raises", "raised RuntimeError: my estimator blew up"),
        ("none", "returned NoneType None, not an Estimate"),
    ],
)
def test_hil_run_ends_in_error_naming_the_estimator_with_the_board_disarmed(mode, said, tmp_path, capsys):
    code = main(
        ["run", "--estimator", f"faulty-{mode}", "--duration", "12", "--no-plots", "--out", str(tmp_path)]
    )
    err = capsys.readouterr().err
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert code == 2, summary["exit"]
    assert summary["exit"].startswith(f"error: estimator 'faulty-{mode}': step at t = "), summary["exit"]
    assert said in summary["exit"]
    assert summary["final_disarm"]["state"] == "DISARMED" and summary["final_disarm"]["ok"]
    assert f"hil run: estimator 'faulty-{mode}': step at t = " in err and "Traceback" not in err


@pytest.mark.parametrize(
    ("mode", "said"),
    [
        ("nan_rows", "returned a non-finite R at step"),
        ("short", "returned t of shape (10,)"),
        ("writes", "raised ValueError: assignment destination is read-only"),
    ],
)
def test_hil_replay_refuses_a_batch_that_is_not_one_estimate_per_step(mode, said, tmp_path):
    options = ReplayOptions(tmp_path / "out", estimator=EstimatorChoice(f"faulty-{mode}"))
    with pytest.raises(PluginError, match=f"estimator 'faulty-{mode}': run over .* steps") as raised:
        replay(LOG, options)
    assert said in str(raised.value)
    assert not (tmp_path / "out" / "summary.json").exists()


def test_the_cli_replay_says_it_in_one_line(tmp_path, capsys):
    args = ["replay", str(LOG), "--estimator", "faulty-nan_rows", "--no-plots", "--out", str(tmp_path)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "hil replay: error: estimator 'faulty-nan_rows'" in err and "Traceback" not in err


class _Broken:
    keys = frozenset()

    def check(self, settings, where):
        raise KeyError("no such thing")  # a kind's own bug, not a ConfigError

    def build(self, settings, site):
        raise ZeroDivisionError("in its constructor")

    def describe(self, settings):
        return "broken"


def test_a_kind_that_raises_in_check_or_build_is_named():
    sys.modules[MODULE].BROKEN = _Broken()  # type: ignore[attr-defined]
    register_estimator("broken", f"{MODULE}:BROKEN")
    with pytest.raises(ConfigError, match="--estimator: estimator 'broken': its check raised KeyError"):
        EstimatorChoice("broken", {}, "--estimator")
    sys.modules[MODULE].NOT_A_KIND = object()  # type: ignore[attr-defined]
    register_estimator("not-a-kind", f"{MODULE}:NOT_A_KIND")
    with pytest.raises(ConfigError, match="is not an EstimatorKind .no keys, check, build, describe"):
        EstimatorChoice("not-a-kind", {}, "--estimator")


# --------------------------------------------------------------------------- the wrapper, by property
def _step(t: float) -> MergedStep:
    return MergedStep(
        t, 0.01, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81), (20.0, 0.0, -40.0), (0.0,) * 3, (True,) * 3, 0
    )


class _Returns:
    """An estimator whose step returns whatever it is given."""

    def __init__(self, out) -> None:
        self.out = out
        self.bias = np.zeros(3)

    def step(self, s):
        return self.out

    def run(self, steps, progress=None):
        return self.out

    @property
    def gyro_bias(self):
        return self.bias

    def set_gyro_bias(self, b):
        self.bias = b
        b[:] = 7.0  # an estimator that keeps the caller's array and changes it

    def set_rest_learning(self, on):
        pass


floats = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    r=st.one_of(
        st.lists(floats, min_size=9, max_size=9),
        st.lists(st.floats(-1.5, 1.5), min_size=9, max_size=9),
        st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)),  # a quaternion
    ),
    w=st.lists(floats, min_size=3, max_size=3),
)
def test_a_step_is_passed_on_only_when_it_is_a_finite_rotation(r, w):
    if len(r) == 4:
        q = np.asarray(r)
        if np.linalg.norm(q) < 1e-3:
            q = np.array([1.0, 0.0, 0.0, 0.0])
        from hil import so3

        R = so3.quat_to_matrix(q / np.linalg.norm(q))
    else:
        R = np.asarray(r).reshape(3, 3)
    out = Estimate(1.0, R, w, np.zeros(3), StepFlag.NONE, 0)
    est = CheckedEstimator(_Returns(out), "mine")
    with np.errstate(all="ignore"):
        rotation = np.isfinite(R).all() and np.abs(R @ R.T - np.eye(3)).max() <= ORTHONORMAL_TOL
        rotation = rotation and np.linalg.det(R) > 0
    # a rate within a phone gyro's reach (RATE_LIMIT): a finite 1000 rad/s was steered on, 114° off
    sane = bool(np.isfinite(w).all() and np.abs(w).max() <= RATE_LIMIT)
    try:
        got = est.step(_step(1.0))
    except PluginError as exc:
        assert exc.plugin == "estimator 'mine'" and "step at t = 1.0 s" in str(exc)
        assert not (rotation and sane)
    else:
        assert got is out and rotation and sane


@settings(max_examples=100, deadline=None)
@given(st.one_of(st.none(), st.integers(), st.text(), st.lists(floats), st.dictionaries(st.text(), floats)))
def test_anything_else_a_step_returns_is_a_plugin_error(out):
    with pytest.raises(PluginError, match="not an Estimate"):
        CheckedEstimator(_Returns(out), "mine").step(_step(1.0))


def test_the_callers_bias_is_not_the_estimators_to_change():
    est = CheckedEstimator(_Returns(None), "mine")
    mine = np.array([0.1, 0.2, 0.3])
    est.set_gyro_bias(mine)
    np.testing.assert_array_equal(mine, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(est.gyro_bias, [7.0, 7.0, 7.0])
    est.inner.bias = [np.nan, 0.0, 0.0]
    with pytest.raises(PluginError, match="gyro_bias is list"):
        est.gyro_bias  # noqa: B018


def test_a_plugin_error_is_the_projects_and_a_runtime_error():
    assert issubclass(PluginError, HilError) and issubclass(PluginError, RuntimeError)
