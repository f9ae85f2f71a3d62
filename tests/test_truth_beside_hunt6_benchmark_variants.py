"""Benchmark recordings with ground truth, varied as other trials of the same benchmarks could really be,
each scored right or refused with one :class:`InputFormatError` naming the file and the field:

- a tyrex ``timeAlignment.txt`` holding two numbers (on one line or two) had its first taken silently as
  the clock offset — which one is the offset is no reader's guess;
- a Qualisys frame that is no rotation (zeros, where a tool wrote an occlusion as 0 rather than NaN; a
  frame scaled) was scored as truth: ``matrix_to_quat`` makes a unit quaternion of anything;
- a QTM export tracking two rigid bodies was scored against the first, whichever was the phone;
- a BROAD ``movement`` mask of NaN (or any value but 0 and 1) counted as "moving": NaN != 0;
- a MATLAB v7.3 (HDF5) file: a BROAD trial saved so was "not a recognised log", a Qualisys export a
  "NotImplementedError" from SciPy.

Every variant is written to ``tmp_path`` from the real files in ``../shared/data`` (never into the
project)."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.logs import read_log
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

TYREX = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_Dist_Phoning"
BROAD = SHARED_DATA / "broad" / "01_undisturbed_slow_rotation_A.mat"
BROAD_SAMPLES = 3000
pytestmark = pytest.mark.skipif(
    not (TYREX.is_dir() and BROAD.is_file()), reason="the shared benchmark recordings are not here"
)


def _qtm() -> tuple[str, dict[str, object]]:
    """The real Qualisys export of :data:`TYREX` as plain fields (its variable's name, its struct)."""
    mat = scipy.io.loadmat(TYREX / "qualisys.mat", squeeze_me=True, struct_as_record=False)
    key = next(k for k in mat if not k.startswith("__"))
    qtm = mat[key]
    fields = {name: getattr(qtm, name) for name in qtm._fieldnames}
    fields["RigidBodies"] = {name: getattr(qtm.RigidBodies, name) for name in qtm.RigidBodies._fieldnames}
    return key, fields


@pytest.fixture(scope="module")
def trial_dir(tmp_path_factory) -> Path:
    """A copy of the real trial (its sensor files) whose ``qualisys.mat``/``timeAlignment.txt`` a test
    rewrites."""
    trial = tmp_path_factory.mktemp("tyrex") / TYREX.name
    shutil.copytree(TYREX, trial)
    for f in trial.iterdir():
        f.chmod(0o644)
    return trial


def write_truth(
    trial: Path, rotations: np.ndarray, names: object = None, alignment: bytes = b"-2.5\n"
) -> None:
    key, fields = _qtm()
    bodies = dict(fields["RigidBodies"])  # type: ignore[arg-type]
    bodies["Rotations"] = rotations
    if names is not None:
        bodies["Name"] = names
    scipy.io.savemat(trial / "qualisys.mat", {key: {**fields, "RigidBodies": bodies}})
    (trial / "timeAlignment.txt").write_bytes(alignment)


REAL_ROTATIONS = _qtm()[1]["RigidBodies"]["Rotations"]  # type: ignore[index]


# ------------------------------------------------------------------------------- timeAlignment.txt
@pytest.mark.parametrize(
    "alignment",
    [b"-2.4 1.0\n", b"-2.4\n-3.0\n", b"-2.4\t0\r\n", b"1.0 -2.4"],
    ids=["two-on-a-line", "two-lines", "tab-crlf", "two-no-eol"],
)
def test_a_time_alignment_of_two_numbers_is_an_error_naming_the_file(trial_dir, alignment):
    write_truth(trial_dir, REAL_ROTATIONS, alignment=alignment)
    with pytest.raises(InputFormatError, match="expected one clock offset") as err:
        read_log(trial_dir)
    assert "timeAlignment.txt" in str(err.value)


@pytest.mark.parametrize(
    ("alignment", "offset"),
    [
        (b"-2.4\n", -2.4),
        (b" -2.400000e+00\r\n", -2.4),
        (b"-2.4", -2.4),
        (b"3.25\n\n", 3.25),
        (b"-0.0\n", 0.0),
    ],
    ids=["plain", "crlf-published-layout", "no-eol", "trailing-blank", "negative-zero"],
)
def test_one_clock_offset_in_any_layout_places_the_truth_by_it(trial_dir, alignment, offset):
    write_truth(trial_dir, REAL_ROTATIONS, alignment=alignment)
    log = read_log(trial_dir)
    assert log.truth is not None
    np.testing.assert_allclose(log.truth.t[:3], np.arange(3) / 60.0 - offset)


# ------------------------------------------------------------------------------- Qualisys frames
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    where=st.sampled_from(["start", "end", "middle", "most"]),
    scale=st.sampled_from([0.0, 2.0, -1.0, 0.9]),
)
def test_a_qualisys_frame_that_is_no_rotation_is_never_scored(trial_dir, where, scale):
    """Frames scaled by ``scale`` (0: an occlusion written as zeros; -1: a reflection) at the trial's
    start, end, middle or over most of it: an error naming Rotations and the first such frame."""
    rot = REAL_ROTATIONS.copy()
    n = rot.shape[1]
    frames = {"start": slice(0, 5), "end": slice(n - 5, n), "middle": slice(n // 2, n // 2 + 1)}.get(
        where, slice(10, n - 10)
    )
    rot[:, frames] *= scale
    first = next(k for k in range(frames.start, frames.stop) if np.isfinite(rot[:, k]).all())
    write_truth(trial_dir, rot)
    with pytest.raises(InputFormatError, match=f"frame {first} is no rotation") as err:
        read_log(trial_dir)
    assert "qualisys.mat" in str(err.value) and "(column Rotations)" in str(err.value)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(where=st.sampled_from(["start", "end", "most"]))
def test_nan_frames_anywhere_are_occlusions_kept_and_not_evaluated(trial_dir, where):
    rot = REAL_ROTATIONS.copy()
    n = rot.shape[1]
    frames = {"start": slice(0, 300), "end": slice(n - 300, n)}.get(where, slice(5, n - 5))
    rot[:, frames] = np.nan
    write_truth(trial_dir, rot)
    log = read_log(trial_dir)
    assert log.truth is not None and len(log.truth) == n
    assert not log.truth.evaluate[frames].any()
    assert log.truth.evaluate.sum() > 0


def test_of_two_rigid_bodies_the_one_named_after_the_phone_is_the_truth(trial_dir):
    """The phone listed second (a table tracked first): the truth is the phone's attitude, noted."""
    table = np.tile(np.eye(3).reshape(9, 1), (1, REAL_ROTATIONS.shape[1]))
    write_truth(
        trial_dir,
        np.stack([table, REAL_ROTATIONS]),
        names=np.array(["Table", "Nexus5-Handler"], dtype=object),
    )
    log = read_log(trial_dir)
    assert log.truth is not None
    k = int(np.flatnonzero(np.isfinite(REAL_ROTATIONS).all(axis=0))[100])
    np.testing.assert_allclose(log.truth.R[k], REAL_ROTATIONS[:, k].reshape(3, 3).T)
    assert any("rigid body 2 of 2 ('Nexus5-Handler'" in note for note in log.notes)


# ------------------------------------------------------------------------------- BROAD
@pytest.fixture(scope="module")
def broad_trial() -> dict[str, np.ndarray]:
    mat = scipy.io.loadmat(BROAD)
    return {
        key: value if key in ("sampling_rate", "info") else value[:BROAD_SAMPLES]
        for key, value in mat.items()
        if not key.startswith("__")
    }


@pytest.mark.parametrize("bad", [np.nan, 2.0, -1.0, 0.5], ids=["nan", "two", "minus-one", "half"])
def test_a_broad_movement_that_is_no_flag_is_an_error_naming_it(tmp_path, broad_trial, bad):
    movement = broad_trial["movement"].astype(float)
    movement[BROAD_SAMPLES // 3 :: 7] = bad
    path = tmp_path / "trial.mat"
    scipy.io.savemat(path, {**broad_trial, "movement": movement})
    with pytest.raises(InputFormatError, match="is no flag, expected 0 or 1") as err:
        read_log(path)
    assert str(path) in str(err.value) and "(column movement)" in str(err.value)


@pytest.mark.parametrize("value", [0, 1], ids=["all-false", "all-true"])
def test_a_broad_movement_all_one_value_evaluates_exactly_it(tmp_path, broad_trial, value):
    quat = broad_trial["opt_quat"].copy()
    quat[:50] = np.nan  # occluded: never evaluated
    quat[BROAD_SAMPLES // 2 :] *= -1.0  # q and -q: one rotation
    path = tmp_path / "trial.mat"
    movement = np.full(broad_trial["movement"].shape, value, np.uint8)
    scipy.io.savemat(path, {**broad_trial, "movement": movement, "opt_quat": quat, "sampling_rate": 100})
    log = read_log(path)
    assert log.truth is not None
    assert log.truth.evaluate.sum() == (BROAD_SAMPLES - 50 if value else 0)
    np.testing.assert_allclose(log.truth.t[1], 0.01)
    assert value or any("nothing will be scored" in note for note in log.notes)


def _v73(path: Path) -> None:
    """A MATLAB v7.3 file's first bytes: the 128-byte MAT header (version 0x0200), HDF5 at byte 512."""
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 .".ljust(116) + bytes(8)
    path.write_bytes(
        (header + struct.pack("<H", 0x0200) + b"IM").ljust(512, b"\0") + b"\x89HDF\r\n\x1a\n" + bytes(512)
    )


def test_a_broad_trial_in_matlab_v73_is_refused_by_name(tmp_path):
    _v73(tmp_path / "trial.mat")
    for given_path in (tmp_path / "trial.mat", tmp_path):
        with pytest.raises(InputFormatError, match=r"MATLAB v7\.3 \(HDF5\)") as err:
            read_log(given_path)
        assert "trial.mat" in str(err.value)


def test_a_qualisys_export_in_matlab_v73_is_refused_by_name(trial_dir):
    write_truth(trial_dir, REAL_ROTATIONS)
    _v73(trial_dir / "qualisys.mat")
    with pytest.raises(InputFormatError, match=r"MATLAB v7\.3 \(HDF5\)") as err:
        read_log(trial_dir)
    assert "qualisys.mat" in str(err.value)


# ------------------------------------------------------------------------------- exclusions by trial
@pytest.mark.parametrize(
    ("name", "intervals"),
    [
        ("Jakob_Nexus5_NoDist_AR", ()),  # Guillaume's NoDist_AR 64-120 s is his, not every NoDist_AR's
        ("Thibaud_iPhone5_NoDist_AR", ()),
        ("Jakob_Nexus5_Dist_Phoning", ((4.7, 5.6), (91.95, 93.2))),
        ("Thibaud_iPhone5_Dist_AR", ((0.0, 2.5), (65.8, 66.5), (87.1, 87.6))),  # at the trial's start
        ("Guillaume_iPhone5_Dist_FrontPocket", ((65.6, 67.2), (100.4, 102.0))),
        ("Guillaume_Nexus5_NoDist_AR", ((64.0, 120.0),)),  # to the evaluated window's end
    ],
)
def test_each_trial_is_evaluated_without_its_own_excluded_intervals_only(
    trial_dir, tmp_path, name, intervals
):
    """Another person's or phone's trial of one condition, read as the real file under its own name: the
    truth frames in its authors' intervals (and only those, with the NaN ones) are not evaluated."""
    trial = tmp_path / name
    shutil.copytree(trial_dir, trial)
    write_truth(trial, REAL_ROTATIONS)
    log = read_log(trial)
    assert log.truth is not None
    t_mocap = np.arange(REAL_ROTATIONS.shape[1]) / 60.0
    expected = np.isfinite(REAL_ROTATIONS).all(axis=0) & (t_mocap <= 120.0)
    for a, b in intervals:
        expected &= ~((t_mocap >= a) & (t_mocap <= b))
    np.testing.assert_array_equal(log.truth.evaluate, expected)
    assert not any("no trial name of the benchmark" in note for note in log.notes)


def test_a_trial_under_a_name_not_the_benchmarks_is_noted_as_without_known_exclusions(trial_dir, tmp_path):
    trial = tmp_path / "my_trial"
    shutil.copytree(trial_dir, trial)
    write_truth(trial, REAL_ROTATIONS)
    log = read_log(trial)
    assert any("'my_trial' is no trial name of the benchmark" in note for note in log.notes)
