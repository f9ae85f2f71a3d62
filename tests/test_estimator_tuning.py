"""The tuned preset is the tuning procedure's result, and it is what ``hil replay`` and the host run.

The procedure itself (bench/estimator_tuning.py, docs/estimator.md "The tuned preset") is checked on small
synthetic tables: the objective takes the worst group and part, leave-one-trial-out never looks at the
left-out trial. Its stored result (bench/estimator_tuning.json) is checked for consistency with itself.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from bench import estimator_tuning as tuning
from hil.estimation.filter import TUNED, FilterConfig
from hil.estimation.registry import EstimatorChoice
from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from hil.logs.replay import ReplayOptions, configure
from hil.scenario import load_scenario
from hil.scenario.paths import FIXTURES


@pytest.fixture(scope="module")
def stored() -> dict:
    return json.loads(tuning.RESULTS.read_text(encoding="utf-8"))


def _same_config(a: FilterConfig, b: FilterConfig) -> None:
    """Every field equal; arrays (E, W, D) elementwise."""
    for f in dataclasses.fields(FilterConfig):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "params":
            for g in dataclasses.fields(x):
                np.testing.assert_array_equal(np.asarray(getattr(x, g.name)), np.asarray(getattr(y, g.name)))
        else:
            assert x == y, f.name


def test_the_code_preset_is_the_stored_tuning_result(stored):
    assert tuning._jsonable(tuning.preset_point()) == stored["preset"]
    assert stored["preset"] == stored["points"][stored["best"]]


def test_the_tuning_evaluates_exactly_the_preset_the_code_builds():
    _same_config(tuning.config(tuning.preset_point()), FilterConfig.tuned())


def test_the_stored_result_is_consistent_with_its_own_table(stored):
    table, vqf = np.array(stored["rmse"]), np.array(stored["vqf_rmse"])
    groups = np.array(stored["groups"])
    scores = [tuning.objective(rows, vqf, groups) for rows in table]
    np.testing.assert_allclose(scores, stored["objective"], rtol=1e-12)
    assert stored["best"] == int(np.argmin(scores))
    held, choices = tuning.leave_one_trial_out(table, vqf, groups)
    assert choices == stored["loto_choices"]
    np.testing.assert_allclose(held, stored["loto_rmse"], rtol=1e-12)
    for g, s in stored["summary"].items():
        np.testing.assert_allclose(s["preset"], table[stored["best"], groups == g].mean(axis=0), rtol=1e-12)
        np.testing.assert_allclose(s["held_out"], held[groups == g].mean(axis=0), rtol=1e-12)


def test_the_objective_is_the_worst_ratio_over_groups_and_parts():
    groups = np.array(["a", "a", "b", "b"])
    vqf = np.ones((4, 3))
    rows = np.full((4, 3), 0.9)
    assert tuning.objective(rows, vqf, groups) == pytest.approx(0.9)
    rows[2:, 2] = 1.3  # group b's inclination worse than VQF's, every total better
    assert tuning.objective(rows, vqf, groups) == pytest.approx(1.3)
    rows[2, 2] = 0.7  # means, not the worst trial: b's inclination (0.7 + 1.3) / 2
    assert tuning.objective(rows, vqf, groups) == pytest.approx(1.0)
    keep = np.array([True, True, True, False])  # without trial 3, b's inclination is 0.7
    assert tuning.objective(rows, vqf, groups, keep) == pytest.approx(0.9)


def test_leave_one_trial_out_chooses_without_the_left_out_trial():
    groups = np.array(["a", "a", "a"])
    vqf = np.ones((3, 3))
    table = np.ones((2, 3, 3))
    table[0] = 0.8  # point 0 better on every trial ...
    table[0, 2] = 5.0  # ... but trial 2
    held, choices = tuning.leave_one_trial_out(table, vqf, groups)
    # trial 2 left out: point 0 wins on trials 0 and 1 and is scored on trial 2; otherwise trial 2 counts
    assert choices == [1, 1, 0]
    np.testing.assert_array_equal(held[2], table[0, 2])
    np.testing.assert_array_equal(held[0], table[1, 0])


def test_hil_replay_runs_the_tuned_preset(tmp_path):
    log = read_log(FIXTURES / "logs" / "simulated_testbed_4s.csv")
    estimator, site, setup = configure(log, ReplayOptions(out_dir=tmp_path, gyro_bias="none"))
    config = estimator.build(site).config
    _same_config(config, FilterConfig.tuned())
    assert any("preset tuned" in line for line in setup)
    assert config.prefilter_rad_s[SensorKind.ACC] == TUNED["acc_cutoff"]


def test_the_host_runs_the_tuned_preset_when_the_scenario_asks_for_it():
    """(The host switches rest learning off once its slew starts: tests/test_runtime.py,
    tests/test_closed_loop.py.)"""
    scenario = load_scenario()
    choice = EstimatorChoice("variational", {"preset": "tuned"})
    tuned = dataclasses.replace(scenario, estimator=choice).make_estimator().config
    assert tuned.params.bias_gain == (TUNED["bias_gain"],) * 3
    assert tuned.mag_gate == TUNED["mag_gate"] and tuned.motion == TUNED["motion"]
    np.testing.assert_array_equal(tuned.params.W, np.diag(TUNED["W_diag"]))
