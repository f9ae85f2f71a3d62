"""The estimator interface: the registry by name, the scenario's ``[estimator]`` table and ``--estimator``,
the default unchanged, and a second estimator — VQF through :mod:`hil.estimation.vqf_adapter` — flown
through ``hil run`` (lockstep, built-in emulator) and replayed through ``hil replay`` on real data."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from hil.cli import main
from hil.estimation.filter import AttitudeFilter, FilterConfig
from hil.estimation.inertial import directions_from_field
from hil.estimation.interface import Estimator, Site
from hil.estimation.registry import EstimatorChoice, estimator_names, register_estimator
from hil.estimation.slots import pack
from hil.logs.replay import ReplayOptions, replay
from hil.scenario import load_scenario, parse_scenario
from hil.scenario.paths import SHARED_DATA
from protocol.errors import ConfigError

HAS_VQF = importlib.util.find_spec("vqf") is not None
needs_vqf = pytest.mark.skipif(not HAS_VQF, reason="the vqf package is not installed (pip install vqf)")

MINIMAL = '[scenario]\nname = "t"\n'


# --------------------------------------------------------------------------- registry and configuration
def test_the_registry_names_both_estimators_and_refuses_an_unknown_one():
    assert {"variational", "vqf"} <= set(estimator_names())
    with pytest.raises(ConfigError, match="unknown estimator 'kalman'.*variational"):
        EstimatorChoice("kalman", {}, "hil run --estimator")


def test_an_estimator_registered_at_run_time_is_chosen_by_its_name():
    register_estimator("paper-again", "hil.estimation.variational_kind:VARIATIONAL")
    choice = EstimatorChoice("paper-again", {"preset": "tuned"})
    assert choice.settings == {"preset": "tuned"}
    assert isinstance(choice.build(load_scenario().estimator_site()), AttitudeFilter)


def test_the_default_scenario_estimator_is_todays_paper_filter():
    """No ``[estimator]`` table, or ``preset`` alone: the variational estimator's paper preset for the
    phone's field, exactly the configuration the host always built."""
    scenario = load_scenario()
    assert scenario.estimator == EstimatorChoice("variational", {"preset": "paper"})
    assert parse_scenario(MINIMAL).estimator == scenario.estimator
    est = scenario.make_estimator()
    assert isinstance(est, AttitudeFilter) and isinstance(est, Estimator)
    expected = FilterConfig.paper(E=directions_from_field(scenario.phone.field_enu_uT))
    np.testing.assert_array_equal(est.config.params.E, expected.params.E)
    assert est.config.prefilter_rad_s == expected.prefilter_rad_s and est.config.init == "measured"


def test_the_estimator_table_names_the_file_and_key_of_a_mistake():
    with pytest.raises(ConfigError, match=r"t\.toml: estimator\.tau_acc_s.*unknown key.*preset"):
        parse_scenario(MINIMAL + '[estimator]\nkind = "variational"\ntau_acc_s = 1.0\n', Path("t.toml"))
    with pytest.raises(ConfigError, match=r"t\.toml: estimator\.preset.*paper, tuned"):
        parse_scenario(MINIMAL + '[estimator]\npreset = "fast"\n', Path("t.toml"))
    with pytest.raises(ConfigError, match=r"t\.toml: estimator\.kind.*unknown estimator 'ekf'"):
        parse_scenario(MINIMAL + '[estimator]\nkind = "ekf"\n', Path("t.toml"))


@needs_vqf
def test_a_scenario_chooses_vqf_with_its_settings():
    table = '[estimator]\nkind = "vqf"\ntau_acc_s = 2.0\nrest_bias = false\n'
    sc = parse_scenario(MINIMAL + table, Path("t.toml"))
    assert sc.estimator.name == "vqf"
    assert sc.estimator.settings["tau_acc_s"] == 2.0 and sc.estimator.settings["rest_bias"] is False
    assert isinstance(sc.make_estimator(), Estimator)
    with pytest.raises(ConfigError, match=r"t\.toml: estimator\.tau_mag_s"):
        parse_scenario(MINIMAL + '[estimator]\nkind = "vqf"\ntau_mag_s = -1\n', Path("t.toml"))


def test_choosing_vqf_without_the_package_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "vqf", None)  # import vqf now raises ImportError
    with pytest.raises(ConfigError, match="pip install vqf"):
        EstimatorChoice("vqf", {}, "hil run --estimator")


def test_a_parameter_array_is_packed_slot_by_slot_and_a_slot_outside_it_is_refused():
    np.testing.assert_array_equal(pack(7, {0: 2.0, 2: [[1.0, 2.0], [3.0, 4.0]]}), [2, 0, 1, 2, 3, 4, 0])
    with pytest.raises(ValueError, match="outside"):
        pack(3, {2: (1.0, 2.0)})


# --------------------------------------------------------------------------- VQF, end to end
@needs_vqf
def test_vqf_step_and_run_give_the_same_numbers_and_turn_to_true_north():
    """Live and batch run the same per-step code; a phone held level with its y axis on magnetic north,
    10° east of true north, is reported at heading 10° east of true north (ENU)."""
    from hil.estimation.sensors import MergedStep, MergedSteps, StepFlag

    decl = 10.0
    site = Site.of_dip(60.0, decl, 0.01)
    choice = EstimatorChoice("vqf")
    n = 400
    mag = np.array([0.0, np.cos(np.radians(60.0)), -np.sin(np.radians(60.0))]) * 48.0
    steps = MergedSteps(
        t=np.arange(n) * 0.01,
        gyr=np.zeros((n, 3)),
        acc=np.tile([0.0, 0.0, 9.81], (n, 1)),
        mag=np.tile(mag, (n, 1)),
        age=np.zeros((n, 3)),
        fresh=np.ones((n, 3), dtype=bool),
        flags=np.zeros(n, dtype=np.int64),
    )
    batch = choice.build(site).run(steps)
    live = choice.build(site)
    for i in range(n):
        t, h = float(steps.t[i]), 0.01 if i else 0.0
        acc, field = (0.0, 0.0, 9.81), (float(mag[0]), float(mag[1]), float(mag[2]))
        s = MergedStep(t, h, (0.0, 0.0, 0.0), acc, field, (0.0, 0.0, 0.0), (True, True, True), StepFlag.NONE)
        est = live.step(s)
        np.testing.assert_array_equal(est.R, batch.R[i])
    heading = np.degrees(np.arctan2(batch.R[-1][0, 1], batch.R[-1][1, 1]))  # the body's y axis in ENU
    assert heading == pytest.approx(decl, abs=0.05)


@needs_vqf
def test_hil_run_flies_vqf_in_lockstep(tmp_path, capsys):
    """``hil run --estimator vqf``: the built-in emulator's spacecraft slews on VQF's estimate; the run
    completes, VQF stepped at the phone's rate, its attitude error small against the world's truth."""
    code = main(["run", "--estimator", "vqf", "--duration", "12", "--no-plots", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert "estimator vqf: VQF (the vqf package)" in err
    assert "(its estimator replaced: --estimator vqf)" in err  # the scenario's text names the paper's
    (run_dir,) = tmp_path.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert code in (0, 1), summary["exit"]  # completed (1: a requirement not met in 12 s)
    assert summary["exit"] == "completed"
    assert summary["slew_started"] and summary["estimator_steps"] > 2000
    assert summary["estimator_rmse_deg"] < 5.0


@needs_vqf
@pytest.mark.skipif(not (SHARED_DATA / "broad").is_dir(), reason="../shared/data is not present")
def test_hil_replay_runs_vqf_on_a_real_trial_with_ground_truth(tmp_path, capsys):
    """``hil replay --estimator vqf`` on 40 s of a BROAD trial (optical ground truth): VQF's own accuracy
    there (3.08° total, 0.30° inclination, tests/test_replay.py), within a margin."""
    trial = SHARED_DATA / "broad" / "01_undisturbed_slow_rotation_A.mat"
    out = tmp_path / "vqf"
    args = [
        "replay",
        str(trial),
        "--estimator",
        "vqf",
        "--window",
        "30",
        "70",
        "--no-plots",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert any(line.startswith("VQF (the vqf package)") for line in summary["setup"])
    assert summary["rmse_deg"]["n"] > 1000
    assert summary["rmse_deg"]["total"] < 4.5 and summary["rmse_deg"]["inclination"] < 0.6
    assert main(["replay", str(trial), "--estimator", "vqf", "--preset", "paper", "--out", str(out)]) == 2
    assert "--preset: is the variational estimator's" in capsys.readouterr().err


@needs_vqf
def test_hil_replay_runs_vqf_on_a_real_phone_export(tmp_path):
    """The real Sensor Logger export (no ground truth): every step estimated, unit quaternions, the bias
    estimate reported."""
    result = replay(
        SHARED_DATA / "sensorlogger-android",
        ReplayOptions(tmp_path, estimator=EstimatorChoice("vqf"), window_s=(0.0, 120.0)),
    )
    assert len(result.estimates) > 5000
    assert np.all(np.isfinite(result.estimates.R)) and np.all(np.isfinite(result.estimates.omega))
    np.testing.assert_allclose(np.linalg.det(result.estimates.R), 1.0, atol=1e-9)
    assert result.gyro_bias is not None and np.all(np.abs(result.gyro_bias) < 0.1)
