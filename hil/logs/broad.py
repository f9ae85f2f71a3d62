"""BROAD (Berlin Robust Orientation Estimation Assessment Dataset, Laidig et al.) trial ``.mat`` files.

Keys: ``imu_gyr`` (N, 3) rad/s, ``imu_acc`` (N, 3) m/s², ``imu_mag`` (N, 3) µT, ``opt_quat`` (N, 4) ground
truth ``[w, x, y, z]`` sensor → ENU, ``movement`` (N,) the samples BROAD evaluates, ``sampling_rate`` (Hz).
All sensors share one clock: sample k at k / sampling_rate. NaN ground-truth rows (occlusions) are kept
and not evaluated. The IMU is a research IMU, not a phone, but its axes are used as the body frame as is.

A ``.mat`` file is whatever MATLAB (or ``scipy.io.savemat``) was given: every variable is checked for what
the reader needs — real numbers (not text, cells or complex values), the shape above, one sampling rate
within :data:`~hil.logs.matfile.RATE_HZ` — and anything else is an :class:`InputFormatError` naming the
variable, never a NumPy error from deep inside the reader.
"""

from __future__ import annotations

import numpy as np

from hil import so3
from hil.estimation.sensors import SensorKind, SensorLog, SensorStream, Truth
from hil.logs.matfile import is_v73, load_mat, mat_variables, one_rate, real_array
from hil.logs.sensorlogger import plain_name
from hil.logs.table import Container
from protocol.errors import InputFormatError

NAME = "broad"
_KEYS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", "sampling_rate")
QUAT_NORM = (0.5, 2.0)
"""The norms a finite ground-truth quaternion may have (BROAD's are 1 to 1e-15): a row of zeros (or any
other non-rotation) is an error naming it, not a rotation made up by normalising it."""


def detect(c: Container) -> bool:
    names = c.names()
    if len(names) != 1 or not plain_name(names[0]).lower().endswith(".mat"):  # TRIAL.MAT, trial.mat.gz too
        return False
    if is_v73(c.raw(names[0])):  # its variables cannot be listed: claimed, so :func:`read` says why not
        return True
    return any(v[0] == "imu_gyr" for v in mat_variables(c, names[0]))


def read(c: Container) -> SensorLog:
    name = c.names()[0]
    where = c.where(name)
    mat = load_mat(c, name, variable_names=_KEYS)
    missing = [k for k in _KEYS if k not in mat]
    if missing:
        raise InputFormatError(f"missing {', '.join(missing)}", where, None, missing[0])
    rate = one_rate(mat["sampling_rate"], "sampling_rate", where)
    arrays = {key: real_array(mat[key], key, where) for key in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat")}
    n = arrays["imu_gyr"].shape[0] if arrays["imu_gyr"].ndim else 0
    for key, width in (("imu_gyr", 3), ("imu_acc", 3), ("imu_mag", 3), ("opt_quat", 4)):
        if arrays[key].shape != (n, width):
            raise InputFormatError(f"shape {arrays[key].shape}, expected ({n}, {width})", where, None, key)
    movement = real_array(mat["movement"], "movement", where).reshape(-1)
    if movement.shape != (n,):
        raise InputFormatError(
            f"{movement.size} values, expected one per sample ({n})", where, None, "movement"
        )
    flags = np.isin(movement, (0.0, 1.0))
    if not flags.all():  # NaN != 0: a mask of NaN was "evaluate everything", silently
        row = int(np.argmin(flags))
        raise InputFormatError(
            f"sample {row}: {float(movement[row])!r} is no flag, expected 0 or 1 "
            f"({int((~flags).sum())} such)",
            where,
            None,
            "movement",
        )
    c.count_samples(3 * n, where, None)
    t = np.arange(n) / rate
    streams = {
        SensorKind.GYR: SensorStream(SensorKind.GYR, t, arrays["imu_gyr"]),
        SensorKind.ACC: SensorStream(SensorKind.ACC, t, arrays["imu_acc"]),
        SensorKind.MAG: SensorStream(SensorKind.MAG, t, arrays["imu_mag"]),
    }
    quat = arrays["opt_quat"]
    finite = np.all(np.isfinite(quat), axis=1)
    norms = np.linalg.norm(np.where(finite[:, None], quat, 1.0), axis=1)
    bad = finite & ~((norms >= QUAT_NORM[0]) & (norms <= QUAT_NORM[1]))
    if bad.any():
        row = int(np.argmax(bad))
        raise InputFormatError(
            f"sample {row}: a quaternion of norm {norms[row]:.3g} is no rotation ({int(bad.sum())} rows)",
            where,
            None,
            "opt_quat",
        )
    r = np.full((n, 3, 3), np.nan)
    r[finite] = so3.quat_to_matrix(quat[finite])
    evaluate = (movement == 1.0) & finite
    truth = Truth(t, r, evaluate)
    notes = [f"BROAD trial at {rate:g} Hz; evaluated on 'movement'"]
    if not evaluate.any():  # said here: the score's "nothing scored" alone blamed the clocks
        notes.append(
            f"truth: 'movement' marks {int(movement.sum())} sample(s), {int(finite.sum())} of {n} finite "
            "opt_quat rows: none is both, nothing will be scored"
        )
    return SensorLog(streams, where, NAME, truth, tuple(notes))
