"""A user's estimator whose estimates are finite rotations at the step's time but whose ``flags`` or
``iterations`` are no step's: bits no :class:`StepFlag` has, a negative count, one past int64. Each is the
estimator's :class:`PluginError` naming it and the step, in ``hil replay`` one line and exit status 2.

Before: they passed the check; ``hil replay --paced`` estimated the whole log and then ended in a raw
``OverflowError: Python int too large to convert to C long`` (its int64 arrays of flags and iterations), and
a flag of -1 read through an estimate's attributes became every StepFlag bit at once."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from plugin_support import Delegating, estimators_in_a_module

from hil.cli import main
from hil.estimation.checked import KNOWN_FLAGS, MAX_ITERATIONS, CheckedEstimator
from hil.estimation.estimator import Estimate, EstimateBatch
from hil.estimation.sensors import MergedStep, MergedSteps, StepFlag
from hil.estimation.variational_kind import VARIATIONAL
from hil.plugins import PluginError

MODULE = "estimate_counts_for_test"
LOG = Path(__file__).resolve().parents[1] / "fixtures" / "logs" / "simulated_testbed_4s.csv"


class Counts(Delegating):
    """The variational estimator, its estimates' flags and iterations replaced from step 100 on by what
    ``mode`` says: as an :class:`Estimate`, or (``read``) an object with an Estimate's six attributes."""

    def __init__(self, inner, mode: str) -> None:
        super().__init__(inner)
        self.mode, self.n = mode, 0

    def step(self, s):
        self.n += 1
        e = self.inner.step(s)
        if self.n < 100:
            return e
        flags, iterations = {
            "iterations_past_int64": (e.flags, 2**70),
            "negative_iterations": (e.flags, -5),
            "flag_bit_70": (StepFlag(1 << 70), 1),
            "read_flags_minus_one": (-1, 1),
        }[self.mode]
        if self.mode.startswith("read_"):
            fields = {k: getattr(e, k) for k in ("t", "R", "omega", "omega_err")}
            return type("Est", (), {**fields, "flags": flags, "iterations": iterations})()
        return Estimate(e.t, e.R, e.omega, e.omega_err, flags, iterations)


class Kind:
    keys = frozenset({"preset"})

    def __init__(self, mode: str) -> None:
        self.mode = mode

    def check(self, settings, where):
        return VARIATIONAL.check(settings, where)

    def build(self, settings, site):
        return Counts(VARIATIONAL.build(settings, site), self.mode)

    def describe(self, settings):
        return f"the variational estimator, its counts {self.mode}"


MODES = ("iterations_past_int64", "negative_iterations", "flag_bit_70", "read_flags_minus_one")


@pytest.fixture(autouse=True)
def _registered() -> Iterator[None]:
    with estimators_in_a_module(MODULE, {f"counts-{mode}": (mode.upper(), Kind(mode)) for mode in MODES}):
        yield


@pytest.mark.parametrize(
    ("mode", "said"),
    [
        ("iterations_past_int64", "returned iterations 1180591620717411303424, not a count from 0 to"),
        ("negative_iterations", "returned iterations -5, not a count from 0 to"),
        ("flag_bit_70", "returned flags 0x400000000000000000, bits no StepFlag has"),
        ("read_flags_minus_one", "returned flags -0x1, bits no StepFlag has"),
    ],
)
def test_hil_replay_says_an_estimates_impossible_counts_in_one_line(mode, said, tmp_path, capsys):
    code = main(["replay", str(LOG), "--paced", "--estimator", f"counts-{mode}", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and "OverflowError" not in err, err
    (line,) = [line for line in err.splitlines() if f"counts-{mode}" in line]
    assert line.startswith(f"hil replay: error: estimator 'counts-{mode}': step at t = "), line
    assert said in line, line


# --------------------------------------------------------------------------- the check, drawn values
class _Returns:
    """An estimator whose step and run return what they are given."""

    def __init__(self, out) -> None:
        self.out = out

    def step(self, s):
        return self.out

    def run(self, steps, progress=None):
        return self.out


def _step(t: float) -> MergedStep:
    return MergedStep(t, 0.01, (0.0,) * 3, (0.0, 0.0, 9.81), (20.0, 0.0, -40.0), (0.0,) * 3, (True,) * 3, 0)


def _a_step(flags: int, iterations: int) -> bool:
    return 0 <= flags <= KNOWN_FLAGS and not flags & ~KNOWN_FLAGS and 0 <= iterations <= MAX_ITERATIONS


counts = st.one_of(
    st.integers(-(2**80), 2**80), st.integers(-3, 2000), st.sampled_from([2**31 - 1, 2**31, 2**63])
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(flags=counts, iterations=counts, read=st.booleans())
def test_a_step_is_passed_on_only_with_step_flags_and_a_count_of_iterations(flags, iterations, read):
    R, w = np.eye(3), np.zeros(3)
    if read:  # an object with an Estimate's attributes, read one by one
        out = type("Est", (), {"t": 1.0, "R": R, "omega": w, "omega_err": w, "flags": flags,
                               "iterations": iterations})()  # fmt: skip
    elif flags >= 0:
        out = Estimate(1.0, R, w, w, StepFlag(flags), iterations)
    else:  # a StepFlag is never negative: an Estimate built by hand with a plain int
        out = tuple.__new__(Estimate, (1.0, flags, iterations, Estimate(1.0, R, w, w, StepFlag(0), 0)[3]))
    est = CheckedEstimator(_Returns(out), "mine")
    try:
        got = est.step(_step(1.0))
    except PluginError as exc:
        assert not _a_step(flags, iterations), exc
        assert "step at t = 1.0 s returned " in str(exc)
    else:
        assert _a_step(flags, iterations)
        assert int(got.flags) == flags and got.iterations == iterations


int_columns = st.one_of(
    st.lists(st.integers(-(2**63), 2**63 - 1), min_size=4, max_size=4).map(lambda v: np.array(v, np.int64)),
    st.lists(st.integers(0, 2**64 - 1), min_size=4, max_size=4).map(lambda v: np.array(v, np.uint64)),
    st.lists(st.integers(0, 1100), min_size=4, max_size=4).map(lambda v: np.array(v, np.int64)),
)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(flags=int_columns, iterations=int_columns)
def test_a_batch_is_passed_on_only_with_step_flags_and_counts_of_iterations(flags, iterations):
    n = 4
    t = np.arange(n) * 0.01
    nan3 = np.zeros((n, 3))
    steps = MergedSteps(t, nan3, nan3, nan3, nan3, np.ones((n, 3), bool), np.zeros(n, np.int64))
    out = EstimateBatch(t.copy(), np.tile(np.eye(3), (n, 1, 1)), nan3.copy(), nan3.copy(), flags, iterations)
    est = CheckedEstimator(_Returns(out), "mine")
    fine = [_a_step(int(f), int(i)) for f, i in zip(flags, iterations, strict=True)]
    try:
        got = est.run(steps)
    except PluginError as exc:
        assert not all(fine), exc
        assert f"at step {fine.index(False)} (t = " in str(exc), exc
    else:
        assert all(fine) and got is out
