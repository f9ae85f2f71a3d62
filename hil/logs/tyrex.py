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

import numpy as np

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream, Truth
from hil.logs.matfile import load_mat, one_rate, real_array
from hil.logs.project_csv import check_seconds
from hil.logs.table import Container, one_copy, read_table
from protocol.errors import InputFormatError

NAME = "tyrex"
EVALUATED_S = (0.0, 120.0)
EXCLUDED: dict[str, tuple[tuple[float, float], ...]] = {
    "Dist_FrontPocket": ((21.2, 21.6),),
    "Dist_Phoning": ((40.5, 40.8),),
    "Dist_Swinging": ((59.7, 60.5), (73.1, 73.5)),
    "NoDist_AR": ((64.0, 120.0),),
}
"""Motion-capture-time intervals (s) the benchmark's authors exclude, by trial condition: the name of a trial
(``Guillaume_Nexus5_Dist_Phoning``) after its person and phone (:func:`excluded`)."""
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
        table = read_table(c, "timeAlignment.txt", None, header=False, use=("col0",), recording=False)
        if not len(table.data):
            raise InputFormatError(f"no clock offset ({table.cut_short})", table.source, None, "col0")
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
    elif rot.ndim == 3 and rot.shape[1] == 9:  # several rigid bodies (B, 9, N): the first
        rot = rot[0]
    if rot.ndim != 2 or rot.shape[0] != 9:
        raise InputFormatError(
            f"RigidBodies.Rotations has shape {rot.shape}, expected (9, N)", where, None, "Rotations"
        )
    n = rot.shape[1]
    r = np.transpose(rot.T.reshape(n, 3, 3), (0, 2, 1))
    t_mocap = np.arange(n) / rate
    evaluate = (t_mocap >= EVALUATED_S[0]) & (t_mocap <= EVALUATED_S[1]) & np.all(np.isfinite(rot), axis=0)
    intervals = excluded(c.name)  # the trial's folder, or its archive's name without .zip
    if intervals:
        for a, b in intervals:
            evaluate &= ~((t_mocap >= a) & (t_mocap <= b))
        notes.append(f"truth: excluded motion-capture intervals {intervals} (benchmark authors)")
    notes.append(f"truth: Qualisys at {rate:g} Hz, phone time = mocap time − ({offset:+g} s)")
    return Truth(t_mocap - offset, r, evaluate)


def excluded(trial: str) -> tuple[tuple[float, float], ...]:
    """The motion-capture intervals (s) the benchmark's authors exclude from the trial named ``trial``
    (:data:`EXCLUDED`): its condition is the whole name, or the name's end after an underscore —
    ``Guillaume_Nexus5_NoDist_Phoning`` is ``NoDist_Phoning``, whose intervals the authors give none of;
    a bare ``endswith`` matched it against ``Dist_Phoning`` and scored it without 40.5–40.8 s."""
    for condition, intervals in EXCLUDED.items():
        if trial == condition or trial.endswith("_" + condition):
            return intervals
    return ()
