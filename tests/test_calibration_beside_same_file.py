"""Two of a calibration command's files that are one file: ``hil calibrate fit -o cal.png --plot cal.png``
saved the plot, wrote the calibration file over it and said it wrote both (status 0); ``--plot`` naming
the bench CSV (or a link to it) drew the picture over the data it was fitted from; ``hil calibrate unit
-o bench/unit0_gimbal_angle.csv --bench-dir bench`` swept, fitted, uploaded and verified, then could not
read its own sweep as the calibration file: the board kept a new set that no file holds. Each is now
refused before anything is read from a board or written, naming both options."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.calibration.generate import generate_bench
from hil.cli import main


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_bench(tmp_path_factory.mktemp("bench"), 1, 5, ())[0].parent


def _alias(target: Path, how: str, where: Path) -> Path:
    """Another name of ``target``: itself, through ``./``, a symbolic link or a hard link (in ``where``)."""
    if how == "same":
        return target
    if how == "dotted":
        return target.parent / "." / target.name
    alias = where / f"alias-{how}{target.suffix}"
    alias.unlink(missing_ok=True)
    if how == "symlink":
        alias.symlink_to(target)
    else:
        os.link(target, alias)
    return alias


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    pair=st.sampled_from(["out-plot", "csv-plot"]),
    how=st.sampled_from(["same", "dotted", "symlink", "hardlink"]),
    exists=st.booleans(),
)
def test_an_output_that_is_another_file_of_the_fit_is_refused_before_anything_is_written(
    bench, tmp_path, capsys, pair, how, exists
):
    work = tmp_path / f"{pair}-{how}-{exists}"
    work.mkdir()
    csv = work / "rotor.png"  # a bench CSV under an image's name: what --plot could name by mistake
    csv.write_bytes((bench / "unit0_rotor.csv").read_bytes())
    if pair == "out-plot":
        first = work / "cal.png"
        if exists or how == "hardlink":  # a hard link needs a file to link to
            first.write_text("")
        out, plot = first, _alias(first, how, work)  # a link to a file not there yet: dangling
    else:
        out, plot = work / "cal.toml", _alias(csv, how, work)
    before = {p: p.read_bytes() for p in work.iterdir() if p.is_file()}
    status = main(["calibrate", "fit", str(csv), "--base", "default", "-o", str(out), "--plot", str(plot)])
    err = capsys.readouterr().err
    assert status == 2, err
    assert f"--plot {plot}: {plot} is the file of " in err and "give each its own file" in err, err
    assert {p: p.read_bytes() for p in work.iterdir() if p.is_file()} == before


def test_calibrate_unit_refuses_an_output_file_that_is_a_bench_csv_before_opening_the_board(tmp_path, capsys):
    """It used to run the whole cycle (8 s here), leave the board holding the new set, and end with
    ``not valid TOML`` for the file that was its own sweep."""
    bench_dir = tmp_path / "bench"
    out = bench_dir / "unit0_gimbal_angle.csv"
    status = main(
        [
            "calibrate",
            "unit",
            "--port",
            "emu://?unit_spread=7&esc_supply_switch=1",
            "--unit",
            "0",
            "--maps",
            "gimbal_angle",
            "-o",
            str(out),
            "--bench-dir",
            str(bench_dir),
        ]
    )
    err = capsys.readouterr().err
    assert status == 2
    assert err.strip() == (
        f"hil calibrate: error: --bench-dir {bench_dir} (unit0_gimbal_angle.csv): {out} is the file of "
        f"-o {out} too: give each its own file"
    )
    assert not bench_dir.exists()
