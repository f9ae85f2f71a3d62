"""The smartphone attitude benchmark of Michel et al. (Inria tyrex team, "benchmarks-attitude-smartphones"):
one folder per trial with per-sensor text files and Qualisys motion-capture ground truth.

Sensor files (gzip, space separated, column 0 time in s, then x y z in the Android sensor frame):
``accelerometer.txt.gz`` (m/s², gravity included), ``gyroscope-calibrated.txt.gz`` (rad/s),
``magnetometer-calibrated.txt.gz`` (µT). The raw ``gyroscope.txt.gz``/``magnetometer.txt.gz`` (whose extra
columns are the OS's bias estimates) are a fallback, noted.

Ground truth (optional): ``qualisys.mat``, a QTM export at ``FrameRate`` Hz whose ``RigidBodies.Rotations``
is (9, N): each column reshaped to 3×3 row-major and transposed is the sensor → ENU rotation; frame k
(0-based) is at motion-capture time k / FrameRate. ``timeAlignment.txt`` holds the seconds to *add* to
phone time to get motion-capture time, so truth is placed on the phone clock at ``k / FrameRate − offset``.
NaN frames are occlusions (kept, not evaluated). Evaluation follows the benchmark: motion-capture time
0–120 s, minus the intervals its authors mark per trial (:data:`EXCLUDED`).
"""

from __future__ import annotations

import math
import re

import numpy as np

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream, Truth
from hil.logs.matfile import load_mat, one_rate, real_array
from hil.logs.project_csv import check_seconds
from hil.logs.table import Container, one_copy, read_table
from protocol.errors import InputFormatError

NAME = "tyrex"
EVALUATED_S = (0.0, 120.0)
EXCLUDED: dict[str, tuple[tuple[float, float], ...]] = {
    "Guillaume_iPhone4S_NoDist_BackPocket": ((21.1, 21.5), (23.6, 24.0)),
    "Guillaume_iPhone5_Dist_FrontPocket": ((65.6, 67.2), (100.4, 102.0)),
    "Guillaume_iPhone5_Dist_Swinging": ((103.5, 104.5),),
    "Guillaume_iPhone5_NoDist_BackPocket": (
        (5.7, 6.1),
        (7.9, 8.5),
        (9.1, 9.6),
        (24.7, 25.3),
        (26.0, 26.5),
        (76.4, 77.3),
    ),
    "Guillaume_Nexus5_Dist_FrontPocket": ((21.2, 21.6),),
    "Guillaume_Nexus5_Dist_Phoning": ((40.5, 40.8),),
    "Guillaume_Nexus5_Dist_Swinging": ((59.7, 60.5), (73.1, 73.5)),
    "Guillaume_Nexus5_NoDist_AR": ((64.0, 120.0),),
    "Jakob_iPhone4S_NoDist_RunningHand": ((34.8, 49.2),),
    "Jakob_iPhone5_NoDist_RunningHand": ((16.0, 17.0), (30.0, 37.5), (39.8, 40.2)),
    "Jakob_Nexus5_Dist_Phoning": ((4.7, 5.6), (91.95, 93.2)),
    "Jakob_Nexus5_Dist_Swinging": ((96.2, 97.5),),
    "Jakob_Nexus5_NoDist_RunningHand": ((36.0, 47.5),),
    "Thibaud_iPhone4S_NoDist_Texting": ((51.4, 51.8),),
    "Thibaud_iPhone5_Dist_AR": ((0.0, 2.5), (65.8, 66.5), (87.1, 87.6)),
    "Thibaud_iPhone5_Dist_FrontPocket": ((52.3, 52.8), (61.2, 61.7)),
    "Thibaud_Nexus5_Dist_FrontPocket": ((40.0, 52.6),),
    "Thibaud_Nexus5_Dist_Phoning": ((10.8, 14.0), (18.0, 19.6), (44.8, 46.4), (87.0, 88.0), (90.4, 91.0)),
    "Thibaud_Nexus5_Dist_Swinging": ((105.45, 105.5),),
    "Thibaud_Nexus5_NoDist_Swinging": ((36.8, 37.2),),
}
"""Motion-capture-time intervals (s) the benchmark's authors exclude, by trial (person, phone, condition:
their ``qualisysErrors``, "added manually", of each trial in ``AttitudeBenchmarks.loadDatasets``). They
are the trial's own, not its condition's: keyed by condition, Guillaume's Nexus 5 intervals were cut out
of Jakob's and Thibaud's trials and every iPhone's (``NoDist_AR``'s 64-120 s: half of each), and the
intervals of those trials were never cut. Every other trial of the benchmark has none (:func:`excluded`)."""
PERSONS = ("Guillaume", "Jakob", "Thibaud")
PHONES = ("iPhone4S", "iPhone5", "Nexus5")
CONDITIONS = tuple(
    f"{d}_{motion}"
    for d in ("Dist", "NoDist")
    for motion in (
        "AR",
        "BackPocket",
        "FrontPocket",
        "Phoning",
        "RunningHand",
        "RunningPocket",
        "Swinging",
        "Texting",
    )
)
"""The benchmark's trials are each named ``{person}_{phone}_{condition}`` of these: a trial named otherwise
has no exclusions known, which :func:`read` notes."""
ROTATION_TOLERANCE = 1e-3
"""The orthonormality error ``‖RᵀR − I‖_F`` up to which a Qualisys frame is a rotation: QTM writes them
orthonormal to 1e-7 (all 14 Nexus 5 trials); a frame of zeros is 1.7, a frame scaled by 2 is 5.2."""
_FILES = {
    SensorKind.ACC: ("accelerometer.txt",),
    SensorKind.GYR: ("gyroscope-calibrated.txt", "gyroscope.txt"),
    SensorKind.MAG: ("magnetometer-calibrated.txt", "magnetometer.txt"),
}
"""Each sensor's files, preferred first: the calibrated one before the raw one; each gzipped (as published,
``.txt.gz``) or not (a trial gunzipped): two copies of one file are read once when their bytes are the
same, refused when they differ (:func:`hil.logs.table.one_copy`)."""
_SENSOR_COLUMNS = ("col0", "col1", "col2", "col3")
"""The columns of a sensor file that are read, by position (the files have no header): time, x, y, z. The
raw files' bias columns after them — or any column a tool added there, text or numbers — are never
parsed."""


def detect(c: Container) -> bool:
    return c.has("accelerometer.txt.gz") or c.has("accelerometer.txt")


def read(c: Container) -> SensorLog:
    notes = ["tyrex smartphone benchmark trial"]
    streams = {}
    read: list[str] = []
    for kind, files in _FILES.items():
        copies = next(((f + ".gz", f) for f in files if c.has(f + ".gz") or c.has(f)), None)
        if copies is None:
            raise InputFormatError(f"missing {files[0]}.gz", str(c.path))
        name, same = one_copy(c, copies)
        if same is not None:
            notes.append(same)
        if "calibrated" not in name and kind is not SensorKind.ACC:
            notes.append(f"{name}: uncalibrated (the OS bias columns are ignored)")
        table = read_table(c, name, None, header=False, min_columns=4, use=_SENSOR_COLUMNS)
        notes.extend(table.layout_notes())
        stream = SensorStream(kind, table.data[:, 0], table.data[:, 1:4])
        check_seconds(stream, table.source, _SENSOR_COLUMNS[0])  # a time in ms: an error naming the file
        streams[kind] = stream
        read.append(name)
    notes.append(f"read {', '.join(read)}")  # named where a sensor's unit is doubted
    truth = _truth(c, notes) if c.has("qualisys.mat") else None
    return SensorLog(streams, str(c.path), NAME, truth, tuple(notes))


def _truth(c: Container, notes: list[str]) -> Truth:
    where = c.where("qualisys.mat")
    offset = 0.0
    if c.has("timeAlignment.txt"):
        table = read_table(c, "timeAlignment.txt", None, header=False, recording=False)
        if not table.data.size:
            raise InputFormatError(f"no clock offset ({table.cut_short})", table.source, None, "col0")
        if table.data.size != 1:  # which of them is the offset? The first taken silently may be the wrong one
            raise InputFormatError(
                f"{table.data.size} numbers ({table.data.shape[0]} line(s) of {table.data.shape[1]}), "
                "expected one clock offset in seconds",
                table.source,
                None,
                "col0",
            )
        offset = float(table.data[0, 0])
        if not math.isfinite(offset):
            raise InputFormatError(
                f"the clock offset {offset!r} is no number of seconds", table.source, None, "col0"
            )
    else:
        notes.append("no timeAlignment.txt: motion-capture and phone clocks taken as equal")
    mat = load_mat(c, "qualisys.mat", squeeze_me=True, struct_as_record=False)
    keys = [k for k in mat if not k.startswith("__")]
    try:
        qtm = mat[keys[0]]
        frame_rate, rotations = qtm.FrameRate, qtm.RigidBodies.Rotations
    except (IndexError, AttributeError) as exc:
        raise InputFormatError(f"not a QTM export with RigidBodies.Rotations ({exc})", where) from None
    rate = one_rate(frame_rate, "FrameRate", where)
    rot = real_array(rotations, "Rotations", where)
    if rot.ndim == 1 and rot.size == 9:  # one frame: loaded squeezed, (9, 1) comes as (9,)
        rot = rot.reshape(9, 1)
    elif rot.ndim == 3 and rot.shape[1] == 9:  # several rigid bodies (B, 9, N): the phone's
        body = _phone_body(getattr(qtm.RigidBodies, "Name", None), rot.shape[0], c.name, notes)
        rot = rot[body]
    if rot.ndim != 2 or rot.shape[0] != 9:
        raise InputFormatError(
            f"RigidBodies.Rotations has shape {rot.shape}, expected (9, N)", where, None, "Rotations"
        )
    n = rot.shape[1]
    r = np.transpose(rot.T.reshape(n, 3, 3), (0, 2, 1))
    tracked = np.all(np.isfinite(rot), axis=0)  # NaN frames: occlusions, kept and not evaluated
    _check_rotations(r, tracked, where)
    t_mocap = np.arange(n) / rate
    evaluate = (t_mocap >= EVALUATED_S[0]) & (t_mocap <= EVALUATED_S[1]) & tracked
    intervals = excluded(c.name)  # the trial's folder, or its archive's name without .zip
    trial = benchmark_trial(c.name)
    if trial is None:
        notes.append(
            f"truth: {c.name!r} is no trial name of the benchmark ({{person}}_{{phone}}_{{condition}}): "
            "the intervals its authors exclude are unknown, none excluded"
        )
    elif c.name in CONDITIONS:
        notes.append(f"truth: {c.name!r} taken as the benchmark's trial {trial} (its condition alone)")
    if intervals:
        for a, b in intervals:
            evaluate &= ~((t_mocap >= a) & (t_mocap <= b))
        notes.append(f"truth: excluded motion-capture intervals {intervals} (benchmark authors)")
    notes.append(f"truth: Qualisys at {rate:g} Hz, phone time = mocap time − ({offset:+g} s)")
    return Truth(t_mocap - offset, r, evaluate)


def _phone_body(names: object, bodies: int, trial: str, notes: list[str]) -> int:
    """The index of the phone's rigid body among ``bodies`` a QTM export tracked: the one whose name's
    first word (``Nexus5`` of ``Nexus5-Handler``) is a word of the trial's name
    (``Guillaume_Nexus5_Dist_AR``); the first when no name or several do (noted, with its name). The first
    was once taken always: a trial that also tracked a table or a second phone listed first was scored
    against that body's attitude."""
    listed = (
        [str(name) for name in np.atleast_1d(np.asarray(names, dtype=object))] if names is not None else []
    )
    words = {word.lower() for word in trial.split("_")}
    matching = [i for i, name in enumerate(listed[:bodies]) if re.split(r"[-_ ]", name)[0].lower() in words]
    if len(matching) == 1:
        notes.append(f"truth: rigid body {matching[0] + 1} of {bodies} ({listed[matching[0]]!r}, the phone)")
        return matching[0]
    shown = repr(listed[0]) if listed else "unnamed"
    notes.append(f"truth: rigid body 1 of {bodies} ({shown}): no one body's name names the trial's phone")
    return 0


def _check_rotations(r: np.ndarray, tracked: np.ndarray, where: str) -> None:
    """:class:`InputFormatError` naming ``Rotations`` and the first frame unless every finite frame of
    ``r`` (N, 3, 3) is a rotation to :data:`ROTATION_TOLERANCE`, determinant +1. A frame of zeros (a tool
    that writes an occlusion as 0 rather than NaN) or any other non-rotation was once scored as truth:
    ``matrix_to_quat`` makes some unit quaternion of anything, so the RMSE took in a made-up attitude."""
    finite = r[tracked]
    if not len(finite):
        return
    error = np.linalg.norm(np.einsum("nji,njk->nik", finite, finite) - np.eye(3), axis=(1, 2))
    bad = ~(error <= ROTATION_TOLERANCE) | ~(np.linalg.det(finite) > 0.0)
    if bad.any():
        first = int(np.argmax(bad))
        frame = int(np.flatnonzero(tracked)[first])
        raise InputFormatError(
            f"frame {frame} is no rotation (orthonormality error {error[first]:.3g}, determinant "
            f"{np.linalg.det(finite[first]):.3g}; {int(bad.sum())} such frames): an occlusion is NaN",
            where,
            None,
            "Rotations",
        )


def excluded(trial: str) -> tuple[tuple[float, float], ...]:
    """The motion-capture intervals (s) the benchmark's authors exclude from the trial named ``trial``
    (:data:`EXCLUDED`, by :func:`benchmark_trial`). ``Guillaume_Nexus5_NoDist_Phoning`` has none; a bare
    ``endswith`` once matched it against ``Dist_Phoning``."""
    name = benchmark_trial(trial)
    return () if name is None else EXCLUDED.get(name, ())


SHARED_SET = "Guillaume_Nexus5"
"""The person and phone of the benchmark's trials shared with this project (``../shared/data``): a folder
named by its condition alone (``Dist_Swinging``) is taken as theirs."""


def benchmark_trial(trial: str) -> str | None:
    """The benchmark's trial (``{person}_{phone}_{condition}``) a folder named ``trial`` holds: its whole
    name, or its name's end after an underscore (a folder a user prefixed); a condition alone is
    :data:`SHARED_SET`'s. None for a name that is none of these: the intervals to exclude are unknown."""
    if trial in CONDITIONS:
        return f"{SHARED_SET}_{trial}"
    names = (f"{p}_{phone}_{c}" for p in PERSONS for phone in PHONES for c in CONDITIONS)
    return next((name for name in names if trial == name or trial.endswith("_" + name)), None)
