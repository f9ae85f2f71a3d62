"""Beside the tested path: a run whose estimate is not a number for a while (the estimator lost itself at
a drawn moment). Steering has no finite command for such a tick (``Saturation.NOT_FINITE``) and gives
none; the run must say so — counted in its summary, one event per episode, named in the requirement's
why — and a warm-up that ends while the estimate is NaN must not start the slew from it (a slew planned
from a NaN attitude is NaN to the run's end: it steered with nothing for 14 s, though the estimate came
back 1 s later).

The fault is injected in the real estimator (its step's output replaced by NaN over a window of the
phone's time); everything else is the real lockstep run: host, emulated board through the protocol,
world."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hil.estimation.estimator import Estimate
from hil.estimation.filter import AttitudeFilter
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_events
from hil.scenario import load_scenario

DURATION_S = 14.0
CONTROL_RATE_HZ = 50.0  # cubesat-1u's


def _nan_estimates_between(monkeypatch: pytest.MonkeyPatch, start_s: float, end_s: float) -> None:
    """The estimator's output is NaN for the steps whose time lies in [start_s, end_s) (phone s)."""
    step = AttitudeFilter.step

    def lost_for_a_while(self: AttitudeFilter, s):  # type: ignore[no-untyped-def]
        e = step(self, s)
        if start_s <= s.t < end_s:
            nan3 = np.full(3, np.nan)
            return Estimate(e.t, np.full((3, 3), np.nan), nan3, nan3, e.flags, e.iterations)
        return e

    monkeypatch.setattr(AttitudeFilter, "step", lost_for_a_while)


def _run(tmp_path):  # type: ignore[no-untyped-def]
    result = run(load_scenario("cubesat-1u"), RunOptions(out_root=tmp_path, duration_s=DURATION_S))
    events = read_events(result.run_dir / "events.jsonl")[0]
    return result.summary, events


@pytest.mark.parametrize(("start_s", "end_s"), [(6.0, 9.0), (7.3, 8.1)])
def test_ticks_steering_had_no_command_for_are_counted_and_logged_once(tmp_path, monkeypatch, start_s, end_s):
    _nan_estimates_between(monkeypatch, start_s, end_s)
    s, events = _run(tmp_path)
    expected = (end_s - start_s) * CONTROL_RATE_HZ
    assert s["unsteered_ticks"] == pytest.approx(expected, abs=3)
    assert s["unsteered_episodes"] == 1
    assert s["unsteered_s"] == pytest.approx(end_s - start_s, abs=0.1)
    kinds = [e["kind"] for e in events]
    assert kinds.count("unsteered") == 1 and kinds.count("steered_again") == 1  # once per episode
    began = next(e for e in events if e["kind"] == "unsteered")
    again = next(e for e in events if e["kind"] == "steered_again")
    assert began["t"] == pytest.approx(start_s, abs=0.1)
    assert again["after_s"] == pytest.approx(end_s - start_s, abs=0.1)
    assert not s["requirement"]["met"]
    assert "no finite command" in s["requirement"]["why"]


def test_an_episode_open_at_the_end_is_counted_to_the_end(tmp_path, monkeypatch):
    _nan_estimates_between(monkeypatch, 12.0, math.inf)
    s, events = _run(tmp_path)
    slew_start = next(e["t"] for e in events if e["kind"] == "slew_start")
    # the run ends DURATION_S after its slew started: the episode ran from 12 s to then
    assert s["unsteered_s"] == pytest.approx(slew_start + DURATION_S - 12.0, abs=0.1)
    assert [e["kind"] for e in events].count("steered_again") == 0
    assert s["exit"] == "completed" and "no finite command" in s["requirement"]["why"]


def test_a_warm_up_ending_on_a_nan_estimate_waits_for_a_usable_one(tmp_path, monkeypatch):
    # cubesat-1u's warm-up is ready at ~3.7 s: the estimate is NaN across that moment
    _nan_estimates_between(monkeypatch, 2.5, 4.5)
    s, events = _run(tmp_path)
    slew = next(e for e in events if e["kind"] == "slew_start")
    assert slew["t"] >= 4.5 - 0.05 and math.isfinite(slew["angle_deg"])
    assert s["unsteered_ticks"] == 0  # it steered on every tick of its slew
    assert s["final_error_deg"] is not None and s["final_error_deg"] < 20.0


def test_the_estimators_rmse_survives_a_nan_window(tmp_path, monkeypatch):
    # 3 s of NaN estimates in a 14 s slew made the whole RMSE NaN, written as null: the figure of the
    # other 11 s lost with it
    _nan_estimates_between(monkeypatch, 6.0, 9.0)
    s, _ = _run(tmp_path)
    assert s["estimator_rmse_deg"] is not None and 0.0 < s["estimator_rmse_deg"] < 10.0
