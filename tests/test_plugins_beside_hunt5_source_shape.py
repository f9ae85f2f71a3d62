"""A user's phone source whose samples are fine but whose figures that shape the run are absurd: a
``rate_hz`` the estimator task cannot drain it at (0.01 Hz, 1e300 Hz), a ``start`` that ends the run before
it began, a truth spinning at 1e300 rad/s. In a real ``hil run`` in lockstep each is the source's
:class:`PluginError` naming it, exit status 2, one line, the board disarmed.

Before: 0.01 Hz drained the phone every 100 s and the run ended 15 s in "lost: phone ... (phone_gap)",
exit 3, naming no plugin; 1e300 Hz ended on "task 'estimator': period must be at least the scheduler's
resolution of 1 ns"; an end before the start ended the run at once, "time limit (the slew never started)";
a truth of 1e300 rad/s was written as the run's true rate and the run said "completed"."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from urllib.parse import parse_qs, urlsplit

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from plugin_support import still_samples

from hil.cli import main
from hil.estimation.checked import RATE_LIMIT
from hil.link import sources
from hil.link.sources import GroundTruth, PhoneSource
from hil.link.sources.checked import MAX_RATE_HZ, MIN_RATE_HZ, CheckedSource
from hil.numbers import finite_number
from hil.plugins import PluginError

MODULE = "source_shape_for_test"


class Shaped(PhoneSource):
    """A phone lying still at 200 Hz of the run's clock, whose ``rate_hz``, end (``start`` returns
    ``origin + end``) and truth's rate about z are what its URL's query says (none: a stream's)."""

    def __init__(self, url, context) -> None:
        self.url, self.next_t = url, None
        self.q = {k: float(v[0]) for k, v in parse_qs(urlsplit(url).query).items()}

    def drain(self, now):
        out, self.next_t = still_samples(now if self.next_t is None else self.next_t, now)
        return out

    def truth(self, now):
        w = self.q.get("truth_w")
        return None if w is None else GroundTruth(np.eye(3), np.array([0.0, 0.0, w]))

    @property
    def rate_hz(self):
        return self.q.get("rate")

    def start(self, origin):
        end = self.q.get("end")
        return None if end is None else origin + end

    def close(self) -> None:
        """Nothing to release."""


@pytest.fixture(autouse=True)
def _registered() -> Iterator[None]:
    module = type(sys)(MODULE)
    module.Shaped = Shaped  # type: ignore[attr-defined]
    sys.modules[MODULE] = module
    sources.register("shaped", f"{MODULE}:Shaped")
    try:
        yield
    finally:
        del sys.modules[MODULE]


@pytest.mark.parametrize(
    ("query", "said"),
    [
        ("rate=0.01", "rate_hz is float 0.01, not None or a rate the estimator task can drain it at (8 to"),
        ("rate=1e300", "rate_hz is float 1e+300, not None or a rate the estimator task can drain it at"),
        ("rate=-0.0", "rate_hz is float -0.0, not None or a rate"),
        ("end=-5", "returned an end time "),
        ("truth_w=1e300", "returned omega of 1e+300 rad/s on an axis, beyond any spacecraft's"),
    ],
)
def test_a_sources_absurd_rate_end_or_truth_ends_the_run_in_error_naming_it(query, said, tmp_path, capsys):
    args = ["run", "--port", "emu://", "--phone", f"shaped://desk?{query}", "--duration", "3", "--no-plots"]
    code = main([*args, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert code == 2, summary["exit"]
    assert summary["exit"].startswith("error: phone source 'shaped': "), summary["exit"]
    assert said in summary["exit"], summary["exit"]
    (line,) = [line for line in err.splitlines() if "phone source 'shaped'" in line]
    assert line == f"hil run: {summary['exit'][len('error: ') :]}" and "Traceback" not in err
    assert summary["final_disarm"]["state"] == "DISARMED" and summary["final_disarm"]["ok"], summary


def test_a_source_with_sane_figures_runs_to_its_end(tmp_path, capsys):
    """Its rate drives the estimator task, its end the run's, its truth is the run's."""
    phone = "shaped://desk?rate=200&end=2&truth_w=0.01"
    args = ["run", "--port", "emu://", "--phone", phone, "--duration", "5", "--no-plots"]
    code = main([*args, "--out", str(tmp_path)])
    capsys.readouterr()
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert code == 1 and summary["exit"] == "time limit (the slew never started)", summary["exit"]
    assert summary["phone_admission"]["accepted"] > 1000  # drained at 200 Hz for its 2 s


# --------------------------------------------------------------------------- the check, drawn values
numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(MIN_RATE_HZ / 2, MAX_RATE_HZ * 2),
    st.integers(-(10**30), 10**30),
    st.sampled_from([MIN_RATE_HZ, MAX_RATE_HZ, -0.0, 0.0, 10**400]),
)


def _source(**q: object) -> CheckedSource:
    inner = Shaped("shaped://desk", None)
    inner.q = q  # type: ignore[assignment]
    return CheckedSource(inner, "shaped")


@settings(max_examples=300, deadline=None)
@given(rate=numbers)
def test_a_rate_is_passed_on_only_when_the_estimator_task_can_drain_at_it(rate):
    try:
        got = _source(rate=rate).rate_hz
    except PluginError as exc:
        assert "rate_hz is " in str(exc)
        hz = finite_number(rate)
        assert hz is None or not MIN_RATE_HZ <= hz <= MAX_RATE_HZ, rate
    else:
        assert MIN_RATE_HZ <= got <= MAX_RATE_HZ and got == float(rate)


@settings(max_examples=300, deadline=None)
@given(end=numbers, origin=st.floats(0.0, 1e6))
def test_an_end_is_passed_on_only_when_it_is_not_before_the_start(end, origin):
    source = _source(end=0.0)
    source.inner.start = lambda o: end  # type: ignore[method-assign]
    try:
        got = source.start(origin)
    except PluginError as exc:
        assert f"start at t = {origin:.6f} s returned " in str(exc)
        t = finite_number(end)
        assert t is None or t < origin, end
    else:
        assert got == float(end) and got >= origin


@settings(max_examples=300, deadline=None)
@given(w=numbers)
def test_a_truth_is_passed_on_only_at_a_rate_a_spacecraft_can_turn(w):
    try:
        got = _source(truth_w=w).truth(1.0)
    except PluginError as exc:
        assert "truth at t = 1.000000 s returned " in str(exc)
        omega = finite_number(w)
        assert omega is None or abs(omega) > RATE_LIMIT, w
    else:
        assert abs(w) <= RATE_LIMIT and got is not None and got.omega[2] == float(w)


def test_a_source_that_ends_after_the_slew_started_says_so(tmp_path, capsys):
    """A source whose end comes after the slew started and before the run's time after it is up: the run
    ends on its time limit, and says the slew had started (it said "the slew never started" of a run
    that had slewed)."""
    phone = "shaped://desk?rate=200&end=7&truth_w=0.01"
    args = ["run", "--port", "emu://", "--phone", phone, "--duration", "30", "--no-plots"]
    code = main([*args, "--out", str(tmp_path)])
    capsys.readouterr()
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["slew_started"], summary
    assert code == 1 and summary["exit"].startswith("time limit (the slew started at t="), summary["exit"]
    assert "the run's time after it not reached" in summary["exit"]
