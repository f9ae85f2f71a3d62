"""Monte Carlo campaigns (hil.montecarlo, ``hil montecarlo``): dispersion files and draws, runs built from
the draws, campaigns on real Dask clusters (a LocalCluster in this process, a LocalCluster reached by its
scheduler address, and the CLI's own process cluster interrupted with SIGINT), failed runs recorded,
interrupted campaigns resumed.

Every run goes through the one closed loop (:func:`hil.runtime.run` in lockstep: host, emulated board,
protocol, world); runs are short (0.5 s warm-up, 1 s after the slew's start) so the file stays around a
minute.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from montecarlo_support import write_quick_scenario

from hil import so3
from hil.cli import main as hil_main
from hil.montecarlo import (
    METRICS,
    TRACES,
    Campaign,
    draw,
    load_dispersions,
    open_client,
    parse_dispersions,
    read_runs,
    read_traces,
    run_campaign,
    run_chunk,
)
from hil.montecarlo.runner import realise
from hil.montecarlo.store import RUNS, TRACE_FILE
from hil.montecarlo.summary import wilson_interval
from hil.scenario import load_scenario
from hil.scenario.paths import ROOT
from protocol.errors import ConfigError, NumericalError

DISPERSIONS = """
[spacecraft]
inertia_scale = { dist = "normal", sigma = 0.05 }
gimbal_misalignment_rad = { dist = "normal", mean = 0.0, sigma = 0.005 }
rotor_offset_m = { dist = "uniform", low = 0.0, high = 1e-3 }
[sensors.gyr]
noise = { dist = "normal", relative_sigma = 0.2, low = 0.0 }
rate_hz = { dist = "choice", values = [180.0, 200.0], weights = [1, 3] }
[initial]
angle_deg = { dist = "uniform", low = 0.0, high = 5.0 }
[manoeuvre]
angle_deg = { dist = "normal", relative_sigma = 0.1 }
axis_tilt_deg = { dist = "uniform", low = 0.0, high = 10.0 }
[link]
outages_per_minute = 90.0
outage_duration_s = { dist = "uniform", low = 0.3, high = 0.6 }
"""


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory) -> Path:
    """cubesat-1u, shortened: 0.5 s warm-up, a 20° slew, 1 s after its start."""
    return write_quick_scenario(tmp_path_factory.mktemp("scenario"))


@pytest.fixture(scope="module")
def scenario(scenario_file):
    return load_scenario(scenario_file)


@pytest.fixture(scope="module")
def dispersion_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("dispersions") / "test.toml"
    path.write_text(DISPERSIONS)
    return path


@pytest.fixture(scope="module")
def client():
    """A real LocalCluster with one single-threaded worker in this process (a thread, not a process:
    starting processes costs seconds, and threads share the GIL; the CLI test below runs the process
    cluster)."""
    with open_client(workers=1, processes=False) as c:
        yield c


@pytest.fixture(scope="module")
def reference(scenario, dispersion_file, client, tmp_path_factory):
    """A 4-run campaign (two chunks of two), run twice into two directories (plots the first time)."""
    campaign = Campaign(scenario, load_dispersions(dispersion_file, scenario), runs=4, seed=11, batch=2)
    dirs = [tmp_path_factory.mktemp(f"mc{k}") for k in range(2)]
    reports = [run_campaign(campaign, d, client, plots=k == 0) for k, d in enumerate(dirs)]
    return campaign, dirs, reports


# --------------------------------------------------------------------------- draws
def test_draws_are_a_pure_function_of_seed_and_index(scenario, dispersion_file):
    d = load_dispersions(dispersion_file, scenario)
    a, b = draw(d, 3, 5), draw(d, 3, 5)
    assert a.columns == b.columns and a.outages == b.outages and a.phone_seed == b.phone_seed
    for key in a.values:
        np.testing.assert_array_equal(a.values[key], b.values[key])
    continuous = [k for k in a.values if k not in ("sensors.gyr.rate_hz", "link.outages_per_minute")]
    for other in (draw(d, 3, 6), draw(d, 4, 5)):  # another index, another seed
        assert other.phone_seed != a.phone_seed
        assert all(not np.array_equal(other.values[k], a.values[k]) for k in continuous)
    # one stream per parameter: a file with one more dispersion draws the others identically
    more = parse_dispersions(
        DISPERSIONS + '\n[sensors.mag]\nbias = { dist = "normal", sigma = 0.2 }\n', scenario
    )
    c = draw(more, 3, 5)
    for key in a.values:
        np.testing.assert_array_equal(c.values[key], a.values[key])
    assert "sensors.mag.bias" in c.values and "sensors.mag.bias" not in a.values


def test_distributions_have_their_stated_shape(scenario, dispersion_file):
    d = load_dispersions(dispersion_file, scenario)
    runs = [draw(d, 0, i) for i in range(400)]
    scale = np.array([r.values["spacecraft.inertia_scale"] for r in runs])
    assert scale.shape == (400, 3)
    assert abs(scale.mean() - 1.0) < 0.01 and abs(scale.std() - 0.05) < 0.006
    offset = np.array([r.values["spacecraft.rotor_offset_m"] for r in runs])
    assert offset.min() >= 0.0 and offset.max() <= 1e-3 and abs(offset.mean() - 5e-4) < 5e-5
    noise = np.array([r.values["sensors.gyr.noise"][0] for r in runs])
    nominal = scenario.phone.gyr.noise
    assert abs(noise.mean() - nominal) < 0.03 * nominal and abs(noise.std() - 0.2 * nominal) < 0.03 * nominal
    rates = np.array([r.values["sensors.gyr.rate_hz"][0] for r in runs])
    assert set(rates) == {180.0, 200.0} and abs(np.mean(rates == 200.0) - 0.75) < 0.07
    angle = np.array([r.values["manoeuvre.angle_deg"][0] for r in runs])
    assert abs(angle.mean() - 20.0) < 0.3  # mean: the scenario's slew angle
    # Poisson, mean 90/min over the board's first warm-up + duration = 1.5 s
    counts = np.array([len(r.outages) for r in runs])
    assert abs(counts.mean() - 2.25) < 0.2 and abs(counts.var() - 2.25) < 0.5
    for r in runs:
        assert all(0.0 <= a < 1.5 and 0.3 <= dur <= 0.6 for a, dur in r.outages)
        assert r.columns["link.outages"] == len(r.outages)
    axes = np.array([r.directions["initial.angle_deg"] for r in runs])
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1.0)
    assert np.all(np.abs(axes.mean(axis=0)) < 0.15)  # no preferred direction


def test_a_run_is_the_scenario_with_its_draws_applied(scenario, dispersion_file):
    d = load_dispersions(dispersion_file, scenario)
    run = draw(d, 2, 7)
    inputs = realise(scenario, run)
    assert inputs.spacecraft is scenario.spacecraft  # the host's controller keeps the nominal one
    true = inputs.true_spacecraft  # the world flies the dispersed one
    assert true is not None and inputs.world_spacecraft is true
    J0 = np.asarray(scenario.spacecraft.bus_inertia)
    np.testing.assert_allclose(
        np.diag(np.asarray(true.bus_inertia)), np.diag(J0) * run.values["spacecraft.inertia_scale"]
    )
    for i, (u0, u) in enumerate(zip(scenario.spacecraft.units, true.units, strict=True)):
        g0, g, s = np.asarray(u0.gimbal_axis), np.asarray(u.gimbal_axis), np.asarray(u.spin_axis)
        tilt = math.acos(np.clip(g0 @ g, -1, 1))
        assert tilt == pytest.approx(abs(run.values["spacecraft.gimbal_misalignment_rad"][i]), abs=1e-9)
        assert abs(g @ s) < 1e-12 and np.linalg.norm(g) == pytest.approx(1.0)
        assert u.rotor_offset_m == run.values["spacecraft.rotor_offset_m"][i]
    assert inputs.phone.gyr.noise == run.values["sensors.gyr.noise"][0]
    assert inputs.phone.acc == scenario.phone.acc  # not dispersed: untouched
    R0, slew = np.asarray(scenario.slew.R0), inputs.slew
    assert math.degrees(so3.angle_between(slew.R0, R0)) == pytest.approx(run.values["initial.angle_deg"][0])
    assert math.degrees(so3.angle_between(slew.R_target, R0)) == pytest.approx(
        run.values["manoeuvre.angle_deg"][0]
    )
    nominal_axis = so3.log(R0.T @ np.asarray(scenario.slew.R_target))
    axis = so3.log(R0.T @ slew.R_target)
    between = math.degrees(
        math.acos(axis @ nominal_axis / np.linalg.norm(axis) / np.linalg.norm(nominal_axis))
    )
    assert between == pytest.approx(run.values["manoeuvre.axis_tilt_deg"][0], abs=1e-6)
    # the outages as the board's own link stalls (firmware-sim's --stall AT:DURATION, board clock)
    assert run.outages and inputs.fault_options["stall"] == [f"{a!r}:{d!r}" for a, d in run.outages]
    assert ("stall", f"{run.outages[0][0]!r}:{run.outages[0][1]!r}") in inputs.firmware_sim_options()
    assert inputs.seed == run.phone_seed  # the phone's noise realisation


# --------------------------------------------------------------------------- bad dispersion files
@pytest.mark.parametrize(
    ("text", "where", "detail"),
    [
        ("[spacecraft]\ninertia_scle = 1.0\n", "bad.toml: spacecraft.inertia_scle", "unknown parameter"),
        ("[spacecrat]\ninertia_scale = 1.0\n", "bad.toml: spacecrat.inertia_scale", "unknown parameter"),
        ("[sensors.gyro]\n", "bad.toml: sensors.gyro", "unknown table"),
        (
            '[initial]\nangle_deg = { dist = "gauss", sigma = 1 }\n',
            "bad.toml: initial.angle_deg.dist",
            "one of",
        ),
        ("[initial]\nangle_deg = { sigma = 1 }\n", "bad.toml: initial.angle_deg.dist", "one of"),
        (
            '[initial]\nangle_deg = { dist = "uniform", low = 1 }\n',
            "bad.toml: initial.angle_deg.high",
            "required",
        ),
        (
            '[initial]\nangle_deg = { dist = "uniform", low = 2, high = 1 }\n',
            "initial.angle_deg.high",
            "below",
        ),
        (
            '[initial]\nangle_deg = { dist = "normal", sigma = 1, sd = 2 }\n',
            "initial.angle_deg.sd",
            "unknown key",
        ),
        ('[initial]\nangle_deg = { dist = "normal", mean = 1 }\n', "initial.angle_deg.sigma", "exactly one"),
        ('[initial]\nangle_deg = { dist = "normal", sigma = -1 }\n', "initial.angle_deg.sigma", "negative"),
        ('[initial]\nangle_deg = { dist = "normal", sigma = "big" }\n', "initial.angle_deg.sigma", "number"),
        (
            '[initial]\nangle_deg = { dist = "choice", values = [1, 2], weights = [1] }\n',
            "angle_deg.weights",
            "2 non-neg",
        ),
        (
            '[initial]\nangle_deg = { dist = "choice", values = [] }\n',
            "initial.angle_deg.values",
            "non-empty",
        ),
        ("[initial]\nangle_deg = true\n", "bad.toml: initial.angle_deg", "number or a distribution"),
        ("[link]\noutages_per_minute = 1.0\n", "bad.toml: link.outage_duration_s", "both"),
        ("[initial\n", "bad.toml", "not valid TOML"),
    ],
)
def test_bad_dispersion_files_name_the_file_and_key(scenario, tmp_path, text, where, detail):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=detail) as info:
        load_dispersions(path, scenario)
    assert where in info.value.where


def test_missing_dispersion_files_are_named(scenario, tmp_path):
    with pytest.raises(ConfigError, match="no such dispersion file"):
        load_dispersions(tmp_path / "nope.toml", scenario)
    with pytest.raises(ConfigError, match="shipped: default"):
        load_dispersions("nonesuch", scenario)
    assert load_dispersions("default", scenario).columns()  # the shipped default reads


# --------------------------------------------------------------------------- campaigns
def test_same_seed_gives_the_same_table_on_a_local_cluster(reference):
    campaign, dirs, reports = reference
    tables = [(d / RUNS).read_text() for d in dirs]
    assert tables[0] == tables[1]  # byte for byte
    results = read_runs(dirs[0])
    assert results.index.tolist() == [0, 1, 2, 3] and results.ok.all() and results.dropped == 0
    assert results.columns[3:] == campaign.dispersions.columns() + list(METRICS)
    # different indices, different runs
    assert len({results.values["spacecraft.inertia_scale.x"][k] for k in range(4)}) == 4
    assert len({results.values["estimator_rmse_deg"][k] for k in range(4)}) == 4
    for k in range(4):  # the drawn parameters in the table are the draws
        run = campaign.draw(k)
        assert results.values["sensors.gyr.noise"][k] == run.values["sensors.gyr.noise"][0]
        assert results.values["failsafe_events"][k] <= len(run.outages)
    assert results.values["failsafe_events"].sum() >= 1  # 0.3-0.6 s outages trip the 0.25 s watchdog
    assert np.all(np.isfinite(results.values["final_error_deg"])) and np.all(results.values["min_delta"] > 0)
    index, traces = read_traces(dirs[0])
    assert index.tolist() == [0, 1, 2, 3] and traces.shape == (4, len(TRACES), 5)  # 1 s at 5 Hz
    assert traces[:, 0, 0] == pytest.approx(
        results.values["peak_error_deg"], abs=5.0
    )  # starts near the slew angle
    summary = json.loads((dirs[0] / "summary.json").read_text())
    assert summary["runs"] == 4 and summary["failed"] == 0 and set(summary["metrics"]) == set(METRICS)
    assert summary["metrics"]["min_delta"]["max"] == pytest.approx(results.values["min_delta"].max())
    passed = summary["requirements"]["gimbal_rate"]["passed"]
    assert passed == int(np.sum(results.values["peak_gimbal_rate"] <= scenario_limit(campaign)))
    assert sorted(reports[0].plots) == ["envelopes", "histograms", "scatter"]
    assert all(p.stat().st_size > 10_000 for p in reports[0].plots.values())
    assert reports[0].completed == 4 and reports[0].skipped == 0 and reports[0].workers == 1
    assert not reports[1].plots


def test_hil_report_redraws_a_campaign_and_prints_its_pass_rates(reference, capsys):
    from hil.cli import main

    _, dirs, _ = reference
    assert not (dirs[1] / "plots").exists()  # the second campaign was run without plots
    assert main(["report", str(dirs[1])]) == 0
    out = capsys.readouterr().out
    assert f"campaign {dirs[1]}: scenario cubesat-1u, seed 11" in out and "gimbal_rate" in out
    for name in ("histograms", "envelopes", "scatter"):
        assert (dirs[1] / "plots" / f"{name}.png").stat().st_size > 10_000 and f"{name}:" in out


def scenario_limit(campaign: Campaign) -> float:
    return campaign.scenario.spacecraft.limits.max_gimbal_rate


def test_failing_runs_are_recorded_with_their_error_and_parameters(scenario, client, tmp_path):
    """An invalid drawn value (a negative gyro noise) fails its run alone; the others complete."""
    text = '[sensors.gyr]\nnoise = { dist = "choice", values = [0.0017, -1.0] }\n'
    dispersions = parse_dispersions(text, scenario, "failing.toml")

    def failing(seed: int) -> set[int]:
        return {i for i in range(4) if draw(dispersions, seed, i).values["sensors.gyr.noise"][0] < 0}

    seed = next(s for s in range(100) if 0 < len(failing(s)) < 3)  # both kinds among the 4 runs
    bad = failing(seed)
    campaign = Campaign(scenario, dispersions, runs=4, seed=seed, batch=4)
    report = run_campaign(campaign, tmp_path, client, plots=False)
    results = read_runs(tmp_path)
    assert report.failed == len(bad) and set(results.errors) == bad
    for i in bad:
        assert "ConfigError" in results.errors[i] and "sensors.gyr.noise" in results.errors[i]
        k = results.index.tolist().index(i)
        assert results.values["sensors.gyr.noise"][k] == -1.0  # its parameters are in the row
        assert np.isnan(results.values["settle_s"][k])
    assert results.ok.sum() == 4 - len(bad)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert [f["index"] for f in summary["failures"]] == sorted(bad)
    assert summary["requirements"]["gimbal_rate"]["passed"] == 4 - len(bad)  # a failed run passes nothing


def test_a_run_failing_mid_simulation_fails_alone(scenario, dispersion_file, monkeypatch):
    """One run of a chunk raising inside its simulation fails alone; the chunk's next run goes on in the
    same process (nothing of the failed run is left behind). (Test hook: the host of one phone seed raises
    once it has taken 300 phone samples.)"""
    from hil.runtime.host import Host

    d = load_dispersions(dispersion_file, scenario)
    short = scenario.with_changes(slew=replace(scenario.slew, duration_s=0.5))
    d = replace(d, scenario=short)
    runs = [draw(d, 1, i) for i in range(3)]
    doomed = runs[1].phone_seed
    feed = Host.feed

    def flaky(self, samples, now=None):
        if self.scenario.seed == doomed and self.counters.samples > 300:
            raise NumericalError("injected failure")
        feed(self, samples, now)

    monkeypatch.setattr(Host, "feed", flaky)
    results = run_chunk(short, runs, 5.0)
    assert [r.index for r in results] == [0, 1, 2]
    assert [r.ok for r in results] == [True, False, True]
    assert results[1].error == "NumericalError: injected failure" and results[1].columns == runs[1].columns
    assert results[0].trace is not None and set(results[0].metrics) == set(METRICS)


def test_an_interrupted_campaign_resumes_and_runs_only_the_missing_runs(
    scenario_file, scenario, dispersion_file, client, tmp_path
):
    """`hil montecarlo` in its own process (a LocalCluster of worker processes) gets SIGINT mid-way, as
    from Ctrl-C in a terminal; the finished runs are on disk, and the same campaign started again (here
    in this process) runs only the others. A torn last line and record (what SIGKILL mid-write leaves)
    are repaired."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "hil", "montecarlo", str(scenario_file), "--runs", "8", "--seed", "3",
           "--dispersions", str(dispersion_file), "--workers", "1", "--batch", "1", "--out", str(out),
           "--no-plots"]  # fmt: skip
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and _rows(out) < 2:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err
    assert "interrupted" in err
    first = read_runs(out)
    done = first.index.tolist()
    assert 2 <= len(done) < 8 and done == list(range(len(done)))  # batch 1, one worker: in order
    with open(out / RUNS, "a") as f:
        f.write("7,ok,,1.0,2.")  # a torn row
    with open(out / TRACE_FILE, "ab") as f:
        f.write(b"\x07\x00\x00")  # a torn record
    before = (out / RUNS).read_text()
    campaign = Campaign(scenario, load_dispersions(dispersion_file, scenario), runs=8, seed=3, batch=6)
    report = run_campaign(campaign, out, client, plots=False)
    assert report.skipped == len(done) and report.completed == 8 - len(done)
    results = read_runs(out)
    assert results.index.tolist() == list(range(8)) and results.dropped == 0 and results.ok.all()
    after = (out / RUNS).read_text()
    assert after.startswith(before[: before.rindex("\n") + 1])  # the first session's rows are untouched
    assert after.count("\n") == 9  # header + 8 rows: nothing ran twice
    index, traces = read_traces(out)
    assert index.tolist() == list(range(8)) and np.all(np.isfinite(traces[:, :, 0]))


def _rows(out: Path) -> int:
    path = out / RUNS
    return max(0, path.read_text().count("\n") - 1) if path.exists() else 0


def test_a_campaign_run_and_hil_run_of_its_scenario_fly_the_same_trajectory(
    scenario, scenario_file, client, tmp_path
):
    """One closed loop: run 0 of a campaign (on Dask, as any campaign) and `hil run` (the CLI, its own
    process, writing a run directory) of the scenario that run flies — the same file with the run's phone
    seed and its drawn link outage as the board's ``[faults] stall`` — give the same trajectory, tick for
    tick, through the outage's failsafe and re-arm."""
    text = "[link]\noutages_per_minute = 40.0\noutage_duration_s = 0.4\n"
    dispersions = parse_dispersions(text, scenario, "outages.toml")
    seed = next(
        s for s in range(200) if [0.3 < a < 1.2 for a, _ in draw(dispersions, s, 0).outages] == [True]
    )  # one outage, after arming (board time 0.1 s), in the spin-up, warm-up or slew: the watchdog fires
    run0 = draw(dispersions, seed, 0)
    campaign = Campaign(scenario, dispersions, runs=1, seed=seed, trace_hz=50.0)  # every control tick
    run_campaign(campaign, tmp_path / "mc", client, plots=False)
    results = read_runs(tmp_path / "mc")
    _, traces = read_traces(tmp_path / "mc")
    assert results.ok.all() and results.values["failsafe_events"][0] >= 1

    stalls = ", ".join(f'"{a!r}:{d!r}"' for a, d in run0.outages)
    toml = scenario_file.read_text().replace("seed = 1\n", f"seed = {run0.phone_seed}\n")
    toml = toml.replace("[faults]\n", f"[faults]\nstall = [{stalls}]\n")
    assert f"seed = {run0.phone_seed}" in toml and "stall = [" in toml
    (tmp_path / "run0.toml").write_text(toml)
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--scenario", str(tmp_path / "run0.toml"), "--no-plots",
         "--out", str(tmp_path / "runs")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    run_dir = next((tmp_path / "runs").iterdir())
    from hil.runtime.runlog import read_telemetry

    tel = read_telemetry(run_dir / "telemetry.csv")
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["failsafe_events"] == results.values["failsafe_events"][0] and summary["rearms"] >= 1
    # the trace runs from the slew's start, through the outage's recovery (phase 0 again) and on
    with open(run_dir / "events.jsonl") as f:
        slew_start = next(e["t"] for e in map(json.loads, f) if e["kind"] == "slew_start")
    slewing = tel["t"] >= slew_start - 1e-9
    point = tel["point_err_deg"][slewing].astype(np.float32)
    est = tel["est_err_deg"][slewing].astype(np.float32)
    assert len(point) == 51 and traces.shape[-1] == 50  # ticks at 0, 0.02 .. 1 s; the trace stops before 1 s
    np.testing.assert_array_equal(point[:50], traces[0, 0])  # pointing error, tick for tick
    np.testing.assert_array_equal(est[:50], traces[0, 1])  # estimator error
    assert summary["estimator_rmse_deg"] == pytest.approx(results.values["estimator_rmse_deg"][0], rel=1e-12)


def test_another_campaign_in_the_same_directory_is_refused(reference, scenario, dispersion_file, client):
    _, dirs, _ = reference
    other = Campaign(scenario, load_dispersions(dispersion_file, scenario), runs=4, seed=12, batch=2)
    with pytest.raises(ConfigError, match="seed 11, not 12") as info:
        run_campaign(other, dirs[0], client)
    assert info.value.where.endswith("campaign.json")


def test_a_scheduler_given_by_address_takes_the_same_path(
    reference, scenario_file, dispersion_file, tmp_path, capsys
):
    """`hil montecarlo --scheduler ADDRESS` against a running cluster: the rows equal the LocalCluster's."""
    from distributed import LocalCluster

    _, dirs, _ = reference
    out = tmp_path / "remote"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        code = hil_main(["montecarlo", str(scenario_file), "--runs", "2", "--seed", "11", "--batch", "2",
                         "--dispersions", str(dispersion_file), "--scheduler", cluster.scheduler_address,
                         "--out", str(out), "--no-plots"])  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    assert "requirement" in printed and "p95" in printed and str(out) in printed
    rows = (out / RUNS).read_text().splitlines()
    reference_rows = (dirs[0] / RUNS).read_text().splitlines()
    assert rows == reference_rows[:3]  # header and runs 0, 1: same chunk, same bytes


def test_cli_help_and_bad_options(capsys, scenario_file, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the default output directory would go here
    with pytest.raises(SystemExit):
        hil_main(["montecarlo", "--help"])
    assert "examples:" in capsys.readouterr().out
    assert hil_main(["montecarlo", str(scenario_file), "--runs", "0", "--no-plots"]) == 2
    assert "--runs: must be an integer in 1..10000000" in capsys.readouterr().err  # the option, named
    assert (
        hil_main(
            [
                "montecarlo",
                str(scenario_file),
                "--runs",
                "2",
                "--scheduler",
                "tcp://127.0.0.1:9",
                "--workers",
                "2",
            ]
        )
        == 2
    )
    assert "--workers is for a local cluster" in capsys.readouterr().err
    for rate in ("nan", "0", "1e160"):
        assert hil_main(["montecarlo", str(scenario_file), "--runs", "2", "--trace-hz", rate]) == 2
        assert "--trace-hz: must be in (0, " in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # nothing created for a campaign that never started


def test_wilson_interval():
    lo, hi = wilson_interval(99, 100)
    assert lo == pytest.approx(0.9455, abs=1e-3) and hi == pytest.approx(0.9982, abs=1e-3)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0
