"""A user's estimator whose step returns an estimate of the right shapes but the wrong kinds of value — a
float for ``flags`` or ``iterations``, text for ``t``, a complex or boolean ``R`` or ``omega`` — at a drawn
step ends ``hil run`` as an error naming the estimator, the step and the field, its board disarmed; a
step's values of the right kinds (numpy's too) are passed on as they are.

Before: each was read through a lossy conversion and steered on: ``flags = 1.5`` became ``GYR_STALE`` (a
bit the plugin never set), ``iterations = 2.9`` became 2, ``t = "3.0"`` a time, a complex ``R`` its real
part (numpy's ComplexWarning only), ``omega = [True, False, False]`` 1 rad/s — the run said completed. A
phone source's samples were already held to real numbers (:mod:`hil.link.sources.checked`)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from plugin_support import Delegating, estimators_in_a_module

from hil.cli import main
from hil.estimation.checked import RATE_LIMIT, CheckedEstimator
from hil.estimation.estimator import Estimate
from hil.estimation.sensors import MergedStep, StepFlag
from hil.estimation.variational_kind import VARIATIONAL
from hil.plugins import PluginError

MODULE = "lossy_hunt6_estimators_for_test"

# field -> a value of the wrong kind that a lossy conversion read as another
WRONG = {
    "flags": [1.5, 3.7, "1", True, np.float64(2.0)],
    "iterations": [2.9, "7", True, np.float32(3.0)],
    "t": ["{t}", True, b"1", None],
    "R": ["complex", "bool", "text", "object"],
    "omega": ["complex", "bool"],
    "omega_err": ["complex", "text"],
}


def _wrong(e: Estimate, field: str, value: object) -> SimpleNamespace:
    """``e`` as an object of its six attributes, ``field`` made ``value``'s kind."""
    fields = {"t": e.t, "R": e.R, "omega": e.omega, "omega_err": e.omega_err, "flags": e.flags,
              "iterations": e.iterations}  # fmt: skip
    if field in ("R", "omega", "omega_err"):
        a = fields[field]
        fields[field] = {
            "complex": a * (1 + 1e-3j),
            "bool": a != 0,
            "text": a.astype(str),
            "object": a.astype(object),
        }[str(value)]
    elif value == "{t}":
        fields[field] = repr(e.t)
    else:
        fields[field] = value
    return SimpleNamespace(**fields)


class Lossy(Delegating):
    """The variational estimator, whose step ``at`` returns ``field`` as ``value``'s kind."""

    def __init__(self, inner, field: str, value: object, at: int) -> None:
        super().__init__(inner)
        self.field, self.value, self.at, self.n = field, value, at, 0

    def step(self, s):
        self.n += 1
        e = self.inner.step(s)
        return _wrong(e, self.field, self.value) if self.n == self.at else e


class LossyKind:
    keys = frozenset({"preset"})

    def __init__(self, field: str, value: object, at: int) -> None:
        self.name, self.field, self.value, self.at = f"lossy-{field}", field, value, at

    def check(self, settings, where):
        return VARIATIONAL.check(settings, where)

    def build(self, settings, site):
        return Lossy(VARIATIONAL.build(settings, site), self.field, self.value, self.at)

    def describe(self, settings):
        return f"the variational estimator, its {self.field} of the wrong kind once"


CLI_CASES = [("flags", 1.5, 700), ("R", "complex", 900), ("t", "{t}", 1500), ("omega", "bool", 1200)]


@pytest.fixture
def lossy() -> Iterator[None]:
    kinds = {f"lossy-{f}": (f"LOSSY_{f.upper()}", LossyKind(f, v, at)) for f, v, at in CLI_CASES}
    with estimators_in_a_module(MODULE, kinds):
        yield


@pytest.mark.parametrize(("field", "value", "at"), CLI_CASES)
def test_hil_run_ends_in_error_naming_the_field_of_the_wrong_kind(lossy, field, value, at, tmp_path, capsys):
    code = main(
        ["run", "--estimator", f"lossy-{field}", "--duration", "10", "--no-plots", "--out", str(tmp_path)]
    )
    err = capsys.readouterr().err
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert code == 2, summary["exit"]
    assert summary["exit"].startswith(f"error: estimator 'lossy-{field.lower()}': step at t = "), summary[
        "exit"
    ]
    assert f"returned {field}" in summary["exit"], summary["exit"]
    assert summary["final_disarm"]["state"] == "DISARMED" and summary["final_disarm"]["ok"]
    assert "Traceback" not in err


def _step(t: float) -> MergedStep:
    return MergedStep(
        t,
        0.005,
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 9.81),
        (20.0, 0.0, -40.0),
        (0.0,) * 3,
        (True,) * 3,
        StepFlag.NONE,
    )


class _Returns:
    def __init__(self, out: object) -> None:
        self.out = out

    def step(self, s):
        return self.out


GOOD = Estimate(1.0, np.eye(3), np.zeros(3), np.zeros(3), StepFlag.NONE, 0)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from([(f, v) for f, values in WRONG.items() for v in values]))
def test_a_value_of_the_wrong_kind_is_refused_naming_it(case):
    field, value = case
    est = CheckedEstimator(_Returns(_wrong(GOOD, field, value)), "mine")
    with pytest.raises(PluginError, match=rf"estimator 'mine': step at t = 1.0 s returned {field}"):
        est.step(_step(1.0))


@settings(max_examples=60, deadline=None)
@given(
    t=st.sampled_from([1.0, np.float64(1.0), np.float32(1.0), 1]),
    flags=st.sampled_from([0, StepFlag.NONE, StepFlag.GYR_STALE, np.int64(1), np.uint8(2)]),
    iterations=st.sampled_from([0, 3, np.int32(7), np.int64(10)]),
    dtype=st.sampled_from([np.float64, np.float32, np.int64]),
)
def test_values_of_the_right_kinds_are_passed_on(t, flags, iterations, dtype):
    out = SimpleNamespace(t=t, R=np.eye(3, dtype=dtype), omega=np.zeros(3, dtype=dtype),
                          omega_err=[0.0, 0, np.float32(0)], flags=flags, iterations=iterations)  # fmt: skip
    got = CheckedEstimator(_Returns(out), "mine").step(_step(1.0))
    assert got.t == 1.0 and got.flags == int(flags) and got.iterations == int(iterations)
    np.testing.assert_array_equal(got.R, np.eye(3))


class _Bias:
    def __init__(self, bias: object) -> None:
        self.bias = bias

    @property
    def gyro_bias(self):
        return self.bias


@settings(max_examples=60, deadline=None)
@given(
    st.one_of(
        st.sampled_from([["0.1", "0", "0"], [True, False, False], np.array([1e-3, 0, 0]) * (1 + 1j)]),
        st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=3, max_size=3).filter(
            lambda b: max(map(abs, b)) > RATE_LIMIT  # beyond any gyroscope's bound: 1e160 rad/s too
        ),
    )
)
def test_a_gyro_bias_of_the_wrong_kind_or_beyond_any_gyroscope_is_refused(bias):
    # it is written to events.jsonl as what the estimator found (its "gyro_bias_online")
    with pytest.raises(
        PluginError, match=r"estimator 'mine': gyro_bias is .*(real numbers|gyroscope's bound)"
    ):
        CheckedEstimator(_Bias(bias), "mine").gyro_bias  # noqa: B018


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3), st.sampled_from([list, np.array, tuple]))
def test_a_gyro_bias_of_real_numbers_within_the_bound_is_passed_on(bias, kind):
    np.testing.assert_array_equal(CheckedEstimator(_Bias(kind(bias)), "mine").gyro_bias, bias)
