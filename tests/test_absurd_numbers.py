"""Numbers that are legal but absurd, at every place a user writes one: a scenario's keys (a warm-up of 10⁹ s,
a plant step of 10⁻¹² s — runs that would never end), a dispersion file's, the command line's
(``--runs 1000000000``, ``--window nan 5``); and documents nested or sized to break their parsers
(scenario, dispersion and calibration TOML). Each is one error naming the file and key (or the option),
before anything runs, in bounded time and memory."""

from __future__ import annotations

import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from measure_support import MB, run_measured

from hil.calibration.files import load_calibration
from hil.cli import main
from hil.montecarlo import Campaign, open_client, parse_dispersions, run_campaign
from hil.montecarlo.dispersions import BOUNDS, draw, load_dispersions
from hil.scenario import SCENARIO_DIR, load_scenario, parse_scenario
from hil.scenario.paths import FIXTURES
from hil.scenario.reader import MAX_PLANT_STEPS, RANGES
from protocol.errors import CalibrationError, ConfigError

BASE = "[scenario]\nname='x'\n"


def one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """Run ``hil ARGV`` in this process: status 2 and one line on stderr, which is returned."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


# --------------------------------------------------------------------------- scenarios
@pytest.mark.parametrize(
    ("text", "key", "detail"),
    [
        ("[controller]\nwarmup_s = 1e9\n", "controller.warmup_s", "0..600 s"),
        ("[controller]\nplant_step_s = 1e-12\n", "controller.plant_step_s", "1e-05..0.001 s"),
        (
            "[scenario]\nname='x'\nduration_s = 86000\n[controller]\nwarmup_s = 600\n",
            "scenario.duration_s",
            "at most 86400 s",
        ),
        (
            "[scenario]\nname='x'\nduration_s = 20000\n[controller]\nplant_step_s = 1e-4\n",
            "scenario.duration_s",
            "plant steps",
        ),
        ("[sensors.gyr]\nrate_hz = 1e9\n", "sensors.gyr.rate_hz", "1..1000 Hz"),
        ("[manoeuvre]\nmax_rate = 1e300\n", "manoeuvre.max_rate", "0.0001..10 rad/s"),
        ("[spacecraft]\nbus_inertia = [1e300, 1, 1]\n", "spacecraft.bus_inertia", "-1000..1000"),
        ("[controller]\nmu = -1e300\n", "controller.mu", "0..1e+06"),
    ],
)
def test_a_scenario_that_could_never_end_is_one_line_naming_file_and_key(tmp_path, capsys, text, key, detail):
    path = tmp_path / "absurd.toml"
    path.write_text(text if text.startswith("[scenario]") else BASE + text)
    start = time.monotonic()
    line = one_line_error(capsys, ["run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path)])
    assert f"absurd.toml: {key}:" in line and detail in line, line
    assert time.monotonic() - start < 10
    assert not any(p.is_dir() for p in tmp_path.iterdir())  # no run was started


def _scalar_keys() -> list[str]:
    """Every scalar key of :data:`RANGES` (vectors are checked element by element: some below)."""
    vectors = {
        "bus_inertia",
        "gimbal_axes",
        "spin_axes",
        "field_enu_uT",
        "axis",
        "initial_axis",
        "gimbal_angles_deg",
    }
    return sorted(k for k in RANGES if k.rsplit(".", 1)[1] not in vectors)


@pytest.mark.parametrize("key", _scalar_keys())
def test_every_number_of_a_scenario_is_bounded_on_both_sides(key):
    lo, hi, _ = RANGES[key]
    table, name = key.rsplit(".", 1)
    table = table.replace("*", "gyr")
    for value in (lo - max(1.0, abs(lo)), hi + max(1.0, abs(hi))):
        with pytest.raises(ConfigError, match=r"must be (within|positive)") as info:
            parse_scenario(f"{BASE}[{table}]\n{name} = {value!r}\n", Path("x.toml"))
        assert info.value.where == f"x.toml: {table}.{name}"


@settings(max_examples=80, deadline=None)
@given(
    key=st.sampled_from(_scalar_keys()),
    value=st.one_of(
        st.floats(allow_nan=False, allow_infinity=False),
        st.floats(min_value=-1e3, max_value=1e3),
        st.integers(-(2**63), 2**63 - 1),
    ),
)
def test_any_number_anywhere_gives_a_bounded_scenario_or_one_config_error(key, value):
    """Hypothesis: whatever number is written at a key, the reader either accepts it — and then every number
    is within its bounds and the run is at most a day of at most 10⁸ plant steps — or says which key."""
    table, name = key.rsplit(".", 1)
    table = table.replace("*", "gyr")
    try:
        sc = parse_scenario(f"{BASE}[{table}]\n{name} = {value!r}\n", Path("x.toml"))
    except ConfigError as exc:
        assert exc.where.startswith("x.toml"), exc
        return
    lo, hi, _ = RANGES[key]
    assert lo <= value <= hi
    length = sc.loop.warmup_s + sc.slew.duration_s
    assert length <= 86_400 and length / sc.loop.plant_step_s <= MAX_PLANT_STEPS


def test_the_shipped_scenarios_are_within_their_bounds():
    for path in sorted(SCENARIO_DIR.glob("*.toml")):
        load_scenario(path)


# --------------------------------------------------------------------------- nested and oversized TOML
NESTED_ARRAY = "deep = " + "[" * 5000 + "]" * 5000 + "\n"  # a RecursionError in tomllib
NESTED_TABLES = "deep = " + "{ a = " * 40 + "1" + " }" * 40 + "\n"  # parses; 41 levels


@pytest.mark.parametrize(
    ("body", "detail"), [(NESTED_ARRAY, "nested deeper"), (NESTED_TABLES, "nested deeper")]
)
def test_a_deeply_nested_scenario_is_one_line_naming_the_file(tmp_path, capsys, body, detail):
    path = tmp_path / "nested.toml"
    path.write_text(BASE + "[manoeuvre]\n" + body)
    line = one_line_error(capsys, ["run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path)])
    assert "nested.toml" in line and "nested deeper than 32 levels" in line, line


def test_a_scenario_larger_than_16_mib_is_refused_without_reading_it_all(tmp_path, capsys):
    path = tmp_path / "big.toml"
    with path.open("w") as f:
        f.write(BASE + "description = '")
        for _ in range(17):
            f.write("x" * MB)
        f.write("'\n")
    line = one_line_error(capsys, ["run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path)])
    assert str(path) in line and "larger than 16777216 bytes" in line


def test_nested_dispersion_and_calibration_files_are_errors_naming_them(tmp_path):
    sc = load_scenario("cubesat-1u")
    path = tmp_path / "d.toml"
    path.write_text("[spacecraft]\n" + NESTED_ARRAY)
    with pytest.raises(ConfigError, match="nested deeper") as info:
        load_dispersions(path, sc)
    assert "d.toml" in str(info.value)
    path.write_text("[spacecraft]\n" + NESTED_TABLES)
    with pytest.raises(ConfigError, match="nested deeper") as info:
        load_dispersions(path, sc)
    assert info.value.where.startswith("d.toml: spacecraft.deep")
    calibration = tmp_path / "calibration.toml"
    calibration.write_text('format = "x"\n' + NESTED_ARRAY)
    with pytest.raises(CalibrationError, match="nested deeper") as info:
        load_calibration(calibration)
    assert str(calibration) in str(info.value)


# --------------------------------------------------------------------------- dispersions
@pytest.mark.parametrize(
    ("line", "key"),
    [
        ("[sensors.gyr]\nrate_hz = { dist = 'uniform', low = 100, high = 1e9 }", "sensors.gyr.rate_hz"),
        ("[sensors.mag]\njitter_s = 5.0", "sensors.mag.jitter_s"),
        (
            "[spacecraft]\ninertia_scale = { dist = 'choice', values = [1, 1e300] }",
            "spacecraft.inertia_scale",
        ),
        ("[manoeuvre]\nangle_deg = { dist = 'normal', mean = 1e6, sigma = 1 }", "manoeuvre.angle_deg"),
    ],
)
def test_a_dispersion_beyond_its_parameter_s_bounds_is_refused_naming_file_and_key(line, key):
    with pytest.raises(ConfigError, match="is outside") as info:
        parse_dispersions(line + "\n", load_scenario("cubesat-1u"), "d.toml")
    assert info.value.where == f"d.toml: {key}"


def test_choice_weights_that_overflow_are_refused():
    text = "[manoeuvre]\nangle_deg = { dist = 'choice', values = [10, 20], weights = [1e308, 1e308] }\n"
    with pytest.raises(ConfigError, match="non-negative numbers") as info:
        parse_dispersions(text, load_scenario("cubesat-1u"), "d.toml")
    assert info.value.where == "d.toml: manoeuvre.angle_deg.weights"


def test_a_wide_normal_draws_within_its_parameter_s_bounds():
    """A normal whose tails pass the parameter's range is clipped into it; one wider than the whole range
    (every draw at an end) is refused, naming the key."""
    sc = load_scenario("cubesat-1u")
    lo, hi = BOUNDS["spacecraft.inertia_scale"]
    sigma = 0.75 * (hi - lo)
    d = parse_dispersions(f"[spacecraft]\ninertia_scale = {{ dist = 'normal', sigma = {sigma} }}\n", sc)
    drawn = np.concatenate([draw(d, 1, i).values["spacecraft.inertia_scale"] for i in range(20)])
    assert np.all((drawn >= lo) & (drawn <= hi)) and np.any(np.abs(drawn) == hi)
    with pytest.raises(ConfigError, match="wider than the parameter's whole range") as info:
        parse_dispersions("[spacecraft]\ninertia_scale = { dist = 'normal', sigma = 1e6 }\n", sc)
    assert info.value.where.endswith("spacecraft.inertia_scale.sigma")


# --------------------------------------------------------------------------- the command line
def test_hil_montecarlo_with_a_billion_runs_is_one_line_in_bounded_memory(tmp_path):
    status, peak, seconds, stderr = run_measured(
        "montecarlo", "cubesat-1u", "--runs", "1000000000", "--out", str(tmp_path / "mc"), "--no-plots"
    )
    assert status == 2
    assert stderr.strip().splitlines() == [
        "hil montecarlo: error: --runs: must be an integer in 1..10000000, got 1000000000"
    ]
    assert peak < 512 * MB and seconds < 60
    assert not (tmp_path / "mc").exists()


@pytest.mark.parametrize(
    ("option", "value"), [("--batch", "0"), ("--batch", "100000"), ("--workers", "100000"), ("--seed", "-1")]
)
def test_hil_montecarlo_bounds_its_other_numbers(capsys, tmp_path, option, value):
    line = one_line_error(
        capsys, ["montecarlo", "cubesat-1u", "--runs", "2", option, value, "--out", str(tmp_path / "mc")]
    )
    assert f"{option}: must be an integer in" in line
    assert not (tmp_path / "mc").exists()


def test_hil_montecarlo_workers_are_bounded_by_this_machines_cores(capsys, tmp_path):
    """1 000 workers asked of a 2-core machine took minutes to start (and could exhaust its memory)."""
    from hil.cli.montecarlo import WORKERS_PER_CORE
    from hil.cores import available_cores

    too_many = str(WORKERS_PER_CORE * available_cores() + 1)
    argv = ["montecarlo", "cubesat-1u", "--runs", "2", "--workers", too_many, "--out", str(tmp_path / "mc")]
    line = one_line_error(capsys, argv)
    assert f"--workers: must be an integer in 1..{WORKERS_PER_CORE * available_cores()}" in line
    assert f"this machine's {available_cores()}" in line and "--scheduler" in line


@pytest.mark.parametrize(
    ("runs", "batch", "workers", "expected"),
    [(1, 4, 8, 1), (9, 4, 8, 3), (100, 4, 2, 2), (8, 1, None, None), (3, 4, None, 1)],
)
def test_a_local_cluster_has_no_more_workers_than_the_campaign_has_tasks(runs, batch, workers, expected):
    import argparse

    from hil.cli.montecarlo import local_workers
    from hil.cores import available_cores

    args = argparse.Namespace(runs=runs, batch=batch, workers=workers, scheduler=None)
    want = expected if expected is not None else min(available_cores(), -(-runs // batch))
    assert local_workers(args) == want
    on_a_scheduler = argparse.Namespace(runs=runs, batch=batch, workers=None, scheduler="tcp://x:1")
    assert local_workers(on_a_scheduler) is None


def test_hil_montecarlo_duration_is_bounded_by_the_run_length(capsys, tmp_path):
    argv = ["montecarlo", "cubesat-1u", "--runs", "2", "--duration", "1e9", "--out", str(tmp_path / "mc")]
    line = one_line_error(capsys, argv)
    assert "--duration: the run's simulated length" in line and "at most 86400 s" in line


class _CountingClient:
    """A Dask client whose ``submit`` calls are counted (everything else is the client's own)."""

    def __init__(self, client: object) -> None:
        self._client = client
        self.submitted = 0

    def __getattr__(self, name: str) -> object:
        return getattr(self._client, name)

    def submit(self, *args: object, **kwargs: object) -> object:
        self.submitted += 1
        return self._client.submit(*args, **kwargs)  # type: ignore[attr-defined]


def test_a_campaign_of_ten_million_runs_holds_nothing_per_run_before_its_first_result(tmp_path):
    """The largest campaign allowed starts like a small one: a few chunks in flight, no list of runs."""
    text = (SCENARIO_DIR / "cubesat-1u.toml").read_text()
    text = text.replace("duration_s = 35.0", "duration_s = 0.2").replace("warmup_s = 2.0", "warmup_s = 0.2")
    sc = parse_scenario(text, Path("quick.toml"))
    campaign = Campaign(sc, parse_dispersions("", sc), runs=10_000_000, seed=1, batch=2)

    class FirstResult(Exception):
        pass

    def stop(result: object, done: int, total: int) -> None:
        assert total == 10_000_000
        raise FirstResult

    # The worker is a process: tracemalloc counts the driver alone, and no thread of this process runs a
    # compiled kernel (which allocates without the GIL) while tracemalloc stops — CPython before 3.12.9
    # can crash then (python/cpython#128679: a CI run died in a worker thread's filter step here).
    with open_client(workers=1, processes=True) as client:
        counting = _CountingClient(client)
        tracemalloc.start()
        try:
            with pytest.raises(FirstResult):
                run_campaign(campaign, tmp_path / "mc", counting, on_result=stop, plots=False)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    assert counting.submitted <= 4  # IN_FLIGHT_PER_WORKER chunks for its one worker
    assert peak < 200 * MB, f"{peak / MB:.0f} MB traced"


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["--window", "nan", "5"], "--window"),
        (["--window", "5", "1"], "--window"),
        (["--lat", "1e9", "--lon", "0", "--date", "2020-01-01"], "--lat"),
        (["--inclination", "inf"], "--inclination"),
        (["--max-gap", "-1"], "--max-gap"),
    ],
)
def test_hil_replay_bounds_its_numbers(capsys, tmp_path, argv, option):
    log = FIXTURES / "logs" / "simulated_testbed_4s.csv"
    line = one_line_error(capsys, ["replay", str(log), "--out", str(tmp_path / "out"), *argv])
    assert f"hil replay: error: {option}: " in line  # the option named once
    assert not (tmp_path / "out").exists()
