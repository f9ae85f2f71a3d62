"""Two writers of one calibration file, and a fit plot that cannot be saved.

Two ``hil calibrate fit`` runs into the same ``-o`` file at once each read it, added their unit and wrote it
back: the file then held one of the two units, though both printed "wrote" and exited 0. And ``write_atomic``
wrote through one fixed ``<name>.tmp``: two writers at once wrote into, renamed and removed each other's
temporary file. Now a fit holds an exclusive lock on the file from reading it to writing it, and each write
has a temporary file of its own.

``hil calibrate fit … --plot /proc/x.png`` exited 2 with "cannot save the plot" after the calibration file
had been changed: now the plot is saved first, and a plot that cannot be saved leaves the file as it was,
saying so.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from hil.calibration.files import UnitEntry, load_calibration, save_calibration
from hil.calibration.generate import generate_bench
from hil.calibration.textfiles import lock_path, locked, write_atomic
from hil.cli import main
from protocol.calibration import default_unit_calibration

HELD_S = 8.0
"""How long the test holds the file's lock while a ``hil calibrate fit`` process wants it: enough for the
old, lockless one to start, fit and write on two busy cores."""


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    generate_bench(out, 2, 3, (1,))
    return out


def _fit_argv(bench, out, unit: int, *more: str) -> list[str]:
    csvs = [str(bench / f"unit{unit}_{k}.csv") for k in ("rotor", "gimbal_rate", "gimbal_angle")]
    return ["calibrate", "fit", *csvs, "-o", str(out), "--unit", str(unit), *more]


def _units(path) -> list[int]:
    return [u.index for u in load_calibration(path).units]


def test_a_fit_waits_for_a_writer_holding_the_file_and_keeps_its_unit(bench, tmp_path):
    out = tmp_path / "cal" / "array.toml"
    assert main(_fit_argv(bench, out, 1)) == 0
    with locked(out):  # another writer's read-modify-write under way: it has read the file (unit 1)
        before = load_calibration(out)
        fit = subprocess.Popen(
            [sys.executable, "-m", "hil", *_fit_argv(bench, out, 0)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        try:
            fit.wait(HELD_S)
        except subprocess.TimeoutExpired:
            pass  # waiting for the lock, as it should
        save_calibration(before.with_unit(UnitEntry(2, "unit2", default_unit_calibration())), out)
    said, _ = fit.communicate(timeout=120)
    assert fit.returncode == 0, said
    assert "wrote" in said and "Traceback" not in said
    assert _units(out) == [0, 1, 2]  # neither writer lost the other's unit
    assert not lock_path(out).exists()  # the lock file goes with the lock
    assert sorted(p.name for p in out.parent.iterdir()) == [
        "array-unit0.png",
        "array-unit1.png",
        "array.toml",
    ]


def test_two_fits_at_once_into_one_file_keep_both_units(bench, tmp_path):
    out = tmp_path / "race.toml"
    runs = [
        subprocess.Popen(
            [sys.executable, "-m", "hil", *_fit_argv(bench, out, unit)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for unit in (0, 1)
    ]
    for run in runs:
        said, _ = run.communicate(timeout=120)
        assert run.returncode == 0 and "wrote" in said, said
    assert _units(out) == [0, 1]


def test_writers_at_once_never_share_a_temporary_file(tmp_path):
    target = tmp_path / "file.toml"
    errors: list[BaseException] = []

    def write(n: int) -> None:
        try:
            for i in range(200):
                write_atomic(target, f"writer = {n}\ni = {i}\n")
        except BaseException as exc:  # noqa: BLE001 - collected, asserted below
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(n,)) for n in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []  # a fixed "file.toml.tmp" renamed away by another writer: "cannot write"
    assert target.read_text().startswith("writer = ")
    assert [p.name for p in tmp_path.iterdir()] == ["file.toml"]  # no temporary file left behind


def test_a_lock_waits_for_the_one_before_it(tmp_path):
    target = tmp_path / "file.toml"
    order: list[str] = []
    with locked(target):
        later = threading.Thread(target=lambda: _take(target, order))
        later.start()
        time.sleep(0.5)
        order.append("first done")
    later.join(30)
    assert order == ["first done", "second"]
    assert not lock_path(target).exists()


def _take(target, order: list[str]) -> None:
    with locked(target):
        order.append("second")


def test_a_plot_that_fails_to_save_leaves_the_calibration_file_unchanged(bench, tmp_path):
    out = tmp_path / "plotfail.toml"
    assert main(_fit_argv(bench, out, 0)) == 0
    before = out.read_bytes()
    done = subprocess.run(
        [sys.executable, "-m", "hil", *_fit_argv(bench, out, 1, "--plot", "/proc/x.png")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert "cannot save the plot" in done.stderr and f"{out} was not written" in done.stderr
    assert "Traceback" not in done.stderr and "wrote" not in done.stdout
    assert out.read_bytes() == before  # unit 1 not added behind an error
    assert _units(out) == [0]
