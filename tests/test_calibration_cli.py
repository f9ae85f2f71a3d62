"""``hil calibrate`` end to end on real files: bench data generated, fitted into a calibration file with a
plot, refitted map by map, shown, turned into test vectors; bad input ends with a clear error, not a
traceback."""

from __future__ import annotations

import json

import pytest

from hil.calibration.files import load_calibration
from hil.calibration.generate import generate_bench
from hil.cli import main
from hil.scenario.paths import FIXTURES
from protocol.calibration import default_unit_calibration

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    assert (
        main(["calibrate", "bench", "--out-dir", str(out), "--units", "2", "--seed", "3", "--mirrored", "1"])
        == 0
    )
    return out


def _csvs(bench, unit, kinds=("rotor", "gimbal_rate", "gimbal_angle")):
    return [str(bench / f"unit{unit}_{k}.csv") for k in kinds]


def test_fit_writes_the_file_and_a_plot_and_prints_residuals(bench, tmp_path, capsys):
    out = tmp_path / "cal" / "set.toml"
    assert main(["calibrate", "fit", *_csvs(bench, 0), "-o", str(out), "--unit", "0", "--name", "alpha"]) == 0
    text = capsys.readouterr().out
    for kind in ("rotor", "gimbal_rate", "gimbal_angle"):
        assert f"{kind} " in text
    assert text.count("residual rms") == 3 and "wrote" in text
    plot = tmp_path / "cal" / "set-unit0.png"
    assert plot.read_bytes()[:8] == PNG and plot.stat().st_size > 20_000
    entry = load_calibration(out).unit(0)
    assert entry.name == "alpha"
    assert (out.parent / entry.fits["rotor"].source).resolve() == (bench / "unit0_rotor.csv").resolve()
    assert entry.fits["gimbal_rate"].points == 101 and entry.fits["gimbal_rate"].residual_unit == "rad/s"


def test_refitting_one_map_keeps_the_others_and_their_provenance(bench, tmp_path, capsys):
    out = tmp_path / "set.toml"
    assert main(["calibrate", "fit", *_csvs(bench, 0), "-o", str(out), "--unit", "0"]) == 0
    before = load_calibration(out).unit(0)
    assert (
        main(
            [
                "calibrate",
                "fit",
                _csvs(bench, 1)[0],
                "-o",
                str(out),
                "--unit",
                "0",
                "--plot",
                str(tmp_path / "r.svg"),
            ]
        )
        == 0
    )
    assert "kept from" in capsys.readouterr().out
    after = load_calibration(out).unit(0)
    assert after.calibration.gimbal_rate == before.calibration.gimbal_rate
    assert after.calibration.gimbal_angle == before.calibration.gimbal_angle
    assert after.calibration.rotor != before.calibration.rotor
    assert after.fits["gimbal_angle"] == before.fits["gimbal_angle"]
    assert after.fits["rotor"].source.endswith("unit1_rotor.csv")
    assert (tmp_path / "r.svg").read_text().lstrip().startswith("<?xml")
    # a second unit from the default gimbal maps; the first unit is untouched
    assert (
        main(["calibrate", "fit", _csvs(bench, 1)[0], "-o", str(out), "--unit", "1", "--base", "default"])
        == 0
    )
    cset = load_calibration(out)
    assert cset.unit(0) == after
    assert cset.unit(1).calibration.gimbal_rate == default_unit_calibration().gimbal_rate
    assert set(cset.unit(1).fits) == {"rotor"}


def test_show_and_vectors(bench, tmp_path, capsys):
    out = tmp_path / "set.toml"
    main(["calibrate", "fit", *_csvs(bench, 1), "-o", str(out), "--unit", "3"])
    capsys.readouterr()
    assert main(["calibrate", "show", str(out), "--hex"]) == 0
    text = capsys.readouterr().out
    cal = load_calibration(out).unit(3).calibration
    assert "unit 3 (unit3): binary set 390 bytes" in text and cal.to_bytes().hex() in text
    vec = tmp_path / "v.json"
    assert main(["calibrate", "vectors", str(out), "-o", str(vec)]) == 0
    doc = json.loads(vec.read_text())
    assert [s["name"] for s in doc["sets"]] == ["default", "set.toml unit 3 (unit3)"]
    assert doc["sets"][1]["hex"] == cal.to_bytes().hex()


@pytest.mark.parametrize(
    ("args", "phrase"),
    [
        (["fit", "{bench}/unit0_rotor.csv", "-o", "{tmp}/new.toml"], "no data for gimbal_rate, gimbal_angle"),
        (
            ["fit", "{bench}/unit0_rotor.csv", "{bench}/unit1_rotor.csv", "-o", "{tmp}/x.toml"],
            "one of 2 rotor CSVs",
        ),
        (["fit", "{tmp}/bad.csv", "-o", "{tmp}/x.toml"], "bad.csv:3 (column rpm): 'fast' is not a number"),
        (
            ["fit", "{bench}/unit0_rotor.csv", "-o", "{tmp}/x.toml", "--base", "{tmp}/none.toml"],
            "no such file",
        ),
        (["fit", "{bench}/unit0_rotor.csv", "-o", "{tmp}/x.toml", "--rotor-knots", "40"], "rotor_knots"),
        (["show", "{tmp}/bad.toml"], "bad.toml: version"),
        (["bench", "--out-dir", "{tmp}/b", "--units", "9"], "--units"),
        (
            [
                "fit",
                "{bench}/unit0_rotor.csv",
                "{bench}/unit0_gimbal_rate.csv",
                "{bench}/unit0_gimbal_angle.csv",
                "-o",
                "{tmp}/x.toml",
                "--unit",
                "8",
            ],
            "unit index: 8 is not a unit number 0..7",
        ),
        (
            ["fit", "{bench}/unit0_rotor.csv", "--base", "default", "-o", "{tmp}/bad.csv/x.toml"],
            "cannot write",
        ),
        (
            [
                "fit",
                "{bench}/unit0_rotor.csv",
                "--base",
                "default",
                "-o",
                "{tmp}/x.toml",
                "--plot",
                "{tmp}/p.nope",
            ],
            "cannot save the plot",
        ),
    ],
)
def test_bad_input_is_a_clear_error_and_exit_code_2(bench, tmp_path, capsys, args, phrase):
    (tmp_path / "bad.csv").write_text("pulse_us,battery_v,rpm\n1000,12,0\n1100,12,fast\n")
    (tmp_path / "bad.toml").write_text('format = "vscmg-hil calibration"\nversion = 7\nunit = []\n')
    argv = ["calibrate", *(a.format(bench=bench, tmp=tmp_path) for a in args)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("hil calibrate: error: ") and phrase in err and "Traceback" not in err


@pytest.mark.parametrize("action", ["fit", "bench", "show", "vectors"])
def test_every_action_teaches_by_example(action, capsys):
    with pytest.raises(SystemExit) as info:
        main(["calibrate", action, "--help"])
    assert info.value.code == 0
    assert "example" in capsys.readouterr().out


def test_the_committed_bench_fixtures_are_what_the_generator_makes(tmp_path):
    generate_bench(tmp_path, n_units=4, seed=1, mirrored=(3,))
    committed = FIXTURES / "calibration" / "bench"
    for path in sorted(tmp_path.iterdir()):
        assert path.read_text() == (committed / path.name).read_text(), path.name
    assert len(list(committed.iterdir())) == 12


def test_the_fit_plot_is_in_the_unit_the_residuals_are_printed_in(bench, tmp_path, capsys):
    """The rotor CSV is in rpm; the fit, its printed residuals and its plot are all rad/s (the residual
    axis once said rpm while the printed residuals were rad/s)."""
    assert "rpm" in (bench / "unit0_rotor.csv").read_text().splitlines()[3]
    svg = tmp_path / "rotor.svg"
    argv = ["calibrate", "fit", _csvs(bench, 0)[0], "-o", str(tmp_path / "s.toml"), "--base", "default"]
    assert main([*argv, "--plot", str(svg)]) == 0
    printed = capsys.readouterr().out
    assert "residual rms" in printed and " rad/s, max " in printed and "rpm" not in printed
    text = svg.read_text()
    # matplotlib draws text as glyph paths; the label strings are kept in comments
    assert "residual (rad/s)" in text and "no-load speed (rad/s)" in text
    assert "rpm" not in text


def _partial(bench, tmp_path, status):
    lines = (bench / "unit0_rotor.csv").read_text().splitlines()
    path = tmp_path / "unit0_rotor.csv"
    path.write_text("\n".join([*lines[:3], f"# status: {status}", *lines[3:]]) + "\n")
    return path


def test_a_partial_bench_csv_is_refused_by_fit_unless_allowed_and_then_flagged(bench, tmp_path, capsys):
    path = _partial(bench, tmp_path, "partial: stopped early: interrupted (SIGINT); 12 of 51 steps")
    out = tmp_path / "set.toml"
    argv = ["calibrate", "fit", str(path), "-o", str(out), "--base", "default"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"{path}: a partial sweep ({path}:4: stopped early: interrupted (SIGINT); 12 of 51 steps)" in err
    assert "--allow-partial" in err and not out.exists()
    assert main([*argv, "--allow-partial"]) == 0
    captured = capsys.readouterr()
    assert f"warning: fitting a partial sweep: {path}:4: stopped early" in captured.err and out.exists()


@pytest.mark.parametrize(
    ("status", "phrase"),
    [
        ("done", "status 'done': need 'complete' or 'partial[: why]'"),
        ("complete\n# status: complete", "a second"),
    ],
)
def test_a_bench_csv_status_is_complete_or_partial(bench, tmp_path, capsys, status, phrase):
    path = _partial(bench, tmp_path, status)
    assert main(["calibrate", "fit", str(path), "-o", str(tmp_path / "s.toml"), "--base", "default"]) == 2
    assert phrase in capsys.readouterr().err


def test_a_complete_bench_csv_is_not_partial(bench, tmp_path):
    from hil.calibration.bench import read_bench_csv

    assert read_bench_csv(_partial(bench, tmp_path, "complete")).partial is None
    assert read_bench_csv(bench / "unit0_rotor.csv").partial is None  # no status: hand-made, complete


@pytest.mark.parametrize(
    ("action", "option", "value", "says"),
    [
        # a step held for ever (its dwell's telemetry kept all the while): bounded, naming the option
        ("sweep", "--dwell", "1e160", "--dwell: 1e+160 must be a positive number of seconds, at most 600"),
        ("sweep", "--settle-max", "601", "--settle-max: 601.0 must be a positive number of seconds"),
        ("sweep", "--settle", "20", "--settle-max: 10.0 must be at least the settle time, 20.0"),
        # a pulse that never reached its first step
        (
            "sweep",
            "--rate-limit",
            "1e-300",
            "--rate-limit: 1e-300 must be a finite number of µs/s, at least 1",
        ),
        # every step unsettled (negative), every step settled (NaN: comparisons with it are false)
        ("sweep", "--tolerance", "-1", "--tolerance: -1.0 must be a finite number > 0"),
        ("sweep", "--tolerance", "nan", "--tolerance: nan must be a finite number > 0"),
        ("unit", "--rotor-tolerance", "nan", "--rotor-tolerance: nan must be a finite number > 0"),
        # a rotor that never turns would pass every point (1) or the lowest (0.2)
        ("unit", "--rotor-tolerance", "1", "--rotor-tolerance: 1.0 of full speed is not below the smallest"),
        ("unit", "--rotor-tolerance", "0.2", "a unit that never moves would pass that point"),
        ("unit", "--rate-tolerance", "0", "--rate-tolerance: 0.0 must be a finite number > 0"),
        ("unit", "--angle-tolerance", "-0.03", "--angle-tolerance: -0.03 must be a finite number > 0"),
    ],
)
def test_board_calibration_numbers_that_never_end_or_never_judge_are_refused_naming_the_option(
    tmp_path, capsys, action, option, value, says
):
    """Refused before the board is opened: one line, exit status 2, nothing written."""
    port = "emu://?unit_spread=7&esc_supply_switch=1"
    out = (
        ["--out-dir", str(tmp_path / "bench")] if action == "sweep" else ["--out", str(tmp_path / "cal.toml")]
    )
    if action == "unit":
        out += ["--bench-dir", str(tmp_path / "bench")]
    assert main(["calibrate", action, "--port", port, "--unit", "0", *out, option, value]) == 2
    assert says in capsys.readouterr().err
    assert not (tmp_path / "bench").exists() and not (tmp_path / "cal.toml").exists()
