"""The command line just beside its tested paths, through real subprocesses of ``hil``:

1. ``hil report RUN_DIR`` of a run whose summary.json is damaged — cut short at a drawn byte, not JSON,
   JSON of the wrong shape, values no run writes — said so on stdout and exited 0: ``hil report runs/* &&
   …`` took a run it could not wholly read for reported. It is an error naming the file (exit 2), after
   the run's rows and readable figures are reported; a good summary still exits 0.
2. ``hil calibrate fit --unit 9`` (a unit no board has) was refused only after every CSV was read and
   fitted, naming "unit index", not the option: refused first, naming ``--unit``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from gcs_support import quick_scenario
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.calibration.generate import generate_bench
from hil.runtime import RunOptions, run

ROOT = Path(__file__).resolve().parents[1]


def hil(*argv: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "MPLCONFIGDIR": tempfile.gettempdir()}
    return subprocess.run(
        [sys.executable, "-m", "hil", *argv], capture_output=True, text=True, timeout=300, cwd=cwd, env=env
    )


# --------------------------------------------------------------------------- 1. a damaged summary.json
@pytest.fixture(scope="module")
def real_run(tmp_path_factory) -> Path:
    """A real short lockstep run's directory, its plots removed."""
    result = run(quick_scenario(), RunOptions(out_root=tmp_path_factory.mktemp("runs"), duration_s=2.0))
    shutil.rmtree(result.run_dir / "plots", ignore_errors=True)
    return result.run_dir


def _with_summary(real_run: Path, text: bytes) -> Path:
    top = Path(tempfile.mkdtemp(prefix="hil-hunt4-"))
    d = top / "run"
    shutil.copytree(real_run, d)
    (d / "summary.json").write_bytes(text)
    return d


def _check_damage_is_an_error(d: Path) -> None:
    try:
        done = hil("report", str(d), "--no-plots")
        assert done.returncode == 2, (done.stdout[-2000:], done.stderr[-2000:])
        assert "Traceback" not in done.stderr
        errors = [line for line in done.stderr.splitlines() if line.startswith("hil report: error: ")]
        assert len(errors) == 1 and f"{d / 'summary.json'}: damaged (" in errors[0], done.stderr
        assert "telemetry rows" in done.stdout and "summary.json damaged" in done.stdout, done.stdout
    finally:
        shutil.rmtree(d.parent)


def test_a_good_summary_is_still_reported_with_status_0(real_run):
    done = hil("report", str(real_run), "--no-plots")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "damaged" not in done.stdout + done.stderr and "exit              completed" in done.stdout


@settings(max_examples=6, deadline=None, suppress_health_check=list(HealthCheck))
@given(cut=st.floats(0.0, 0.999))
def test_a_summary_cut_short_anywhere_is_an_error_naming_it(real_run, cut):
    """A run killed as it wrote summary.json (a disk filled) leaves it cut at any byte."""
    whole = (real_run / "summary.json").read_bytes()
    _check_damage_is_an_error(_with_summary(real_run, whole[: int(cut * len(whole))]))


@pytest.mark.parametrize(
    "text",
    [b"", b"\xff\xfe\x00garbage", b"not json", b"[1, 2, 3]", b'"completed"', b"null", b"3.5"],
    ids=["empty", "binary", "words", "a-list", "a-string", "null", "a-number"],
)
def test_a_summary_that_is_not_a_run_summary_is_an_error_naming_it(real_run, text):
    _check_damage_is_an_error(_with_summary(real_run, text))


@settings(max_examples=6, deadline=None, suppress_health_check=list(HealthCheck))
@given(
    key=st.sampled_from(["failsafe_events", "board_resets", "settle_s", "final_error_deg", "exit", "faults"]),
    value=st.sampled_from(["-3", "true", '"x"', "[1]", '{"a": 1}', "NaN", "-Infinity", "2.5"]),
)
def test_a_summary_with_a_value_no_run_writes_is_an_error_naming_it(real_run, key, value):
    summary = json.loads((real_run / "summary.json").read_text())
    text = json.dumps({**summary, key: None}).replace(f'"{key}": null', f'"{key}": {value}')
    d = _with_summary(real_run, text.encode())
    if key in ("settle_s", "final_error_deg") and value == "2.5":  # a figure a run does write
        try:
            done = hil("report", str(d), "--no-plots")
            assert done.returncode == 0 and "damaged" not in done.stdout + done.stderr, done.stderr
        finally:
            shutil.rmtree(d.parent)
        return
    _check_damage_is_an_error(d)


def test_with_several_dirs_the_damaged_one_is_counted_and_the_rest_reported(real_run):
    d = _with_summary(real_run, b'{"exit": "compl')
    try:
        done = hil("report", str(d), str(real_run), "--no-plots")
        assert done.returncode == 2, done.stderr
        assert done.stdout.count("telemetry rows") == 2 and "exit              completed" in done.stdout
        assert "1 of 2 directories not reported" in done.stderr
    finally:
        shutil.rmtree(d.parent)


# --------------------------------------------------------------------------- 2. calibrate fit --unit
@pytest.fixture(scope="module")
def bench(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bench")
    generate_bench(out, 1, 1, ())
    return out


@settings(max_examples=5, deadline=None, suppress_health_check=list(HealthCheck))
@given(unit=st.one_of(st.integers(8, 2**70), st.integers(-(2**70), -1), st.sampled_from([8, -1])))
def test_a_unit_no_board_has_is_refused_before_any_csv_is_read(bench, tmp_path_factory, unit):
    """A CSV that is not a bench CSV beside the good ones: the old command read it (and fitted the others)
    before the unit was looked at, and said the CSV was bad; the unit is refused first, naming --unit."""
    work = tmp_path_factory.mktemp("fit")
    junk = work / "junk.csv"
    junk.write_text("not,a,bench\n1,2,3\n")
    out = work / "set.toml"
    done = hil(
        "calibrate", "fit", str(bench / "unit0_rotor.csv"), str(junk), "-o", str(out), "--unit", str(unit)
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == (
        f"hil calibrate: error: --unit: unit index: {unit} is not a unit number 0..7"
    ), done.stderr
    assert not out.exists() and not list(work.glob("*.png"))


def test_the_last_unit_a_board_has_is_still_fitted(bench, tmp_path):
    out = tmp_path / "set.toml"
    csvs = [str(bench / f"unit0_{k}.csv") for k in ("rotor", "gimbal_rate", "gimbal_angle")]
    done = hil("calibrate", "fit", *csvs, "-o", str(out), "--unit", "7")
    assert done.returncode == 0, done.stderr
    assert out.is_file() and (tmp_path / "set-unit7.png").is_file()


def test_a_base_file_without_the_unit_is_refused_before_any_csv_is_read(bench, tmp_path):
    """``--base FILE`` of a file with no such unit: refused after every CSV was read and fitted (a bad CSV
    beside the good one was said first); now before, naming the file."""
    base = tmp_path / "base.toml"
    csvs = [str(bench / f"unit0_{k}.csv") for k in ("rotor", "gimbal_rate", "gimbal_angle")]
    assert hil("calibrate", "fit", *csvs, "-o", str(base), "--unit", "0").returncode == 0
    junk = tmp_path / "junk.csv"
    junk.write_text("not,a,bench\n1,2,3\n")
    out = tmp_path / "set.toml"
    done = hil("calibrate", "fit", csvs[0], str(junk), "-o", str(out), "--unit", "3", "--base", str(base))
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.strip().splitlines()[-1] == f"hil calibrate: error: {base}: has no unit 3", done.stderr
    assert not out.exists()
