"""BROAD (Berlin Robust Orientation Estimation Assessment Dataset, Laidig et al.) trial ``.mat`` files.

Keys: ``imu_gyr`` (N, 3) rad/s, ``imu_acc`` (N, 3) m/s², ``imu_mag`` (N, 3) µT, ``opt_quat`` (N, 4) ground
truth ``[w, x, y, z]`` sensor → ENU, ``movement`` (N,) the samples BROAD evaluates, ``sampling_rate`` (Hz).
All sensors share one clock: sample k at k / sampling_rate. NaN ground-truth rows (occlusions) are kept
and not evaluated. The IMU is a research IMU, not a phone, but its axes are used as the body frame as is.
"""

from __future__ import annotations

import numpy as np

from hil import so3
from hil.estimation.sensors import SensorKind, SensorLog, SensorStream, Truth
from hil.logs.matfile import load_mat, mat_variables
from hil.logs.table import Container
from protocol.errors import InputFormatError

NAME = "broad"
_KEYS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", "sampling_rate")


def detect(c: Container) -> bool:
    names = c.names()
    if len(names) != 1 or not names[0].endswith(".mat"):
        return False
    return any(v[0] == "imu_gyr" for v in mat_variables(c, names[0]))


def read(c: Container) -> SensorLog:
    name = c.names()[0]
    where = c.where(name)
    mat = load_mat(c, name, variable_names=_KEYS)
    missing = [k for k in _KEYS if k not in mat]
    if missing:
        raise InputFormatError(f"missing {', '.join(missing)}", where, None, missing[0])
    rate = float(np.asarray(mat["sampling_rate"]).reshape(-1)[0])
    n = np.asarray(mat["imu_gyr"]).shape[0]
    for key, width in (("imu_gyr", 3), ("imu_acc", 3), ("imu_mag", 3), ("opt_quat", 4)):
        if np.asarray(mat[key]).shape != (n, width):
            raise InputFormatError(
                f"shape {np.asarray(mat[key]).shape}, expected ({n}, {width})", where, None, key
            )
    if not rate > 0:
        raise InputFormatError(f"sampling rate {rate!r}", where, None, "sampling_rate")
    c.count_samples(3 * n, where, None)
    t = np.arange(n) / rate
    streams = {
        SensorKind.GYR: SensorStream(SensorKind.GYR, t, mat["imu_gyr"]),
        SensorKind.ACC: SensorStream(SensorKind.ACC, t, mat["imu_acc"]),
        SensorKind.MAG: SensorStream(SensorKind.MAG, t, mat["imu_mag"]),
    }
    quat = np.asarray(mat["opt_quat"], dtype=float)
    finite = np.all(np.isfinite(quat), axis=1)
    r = np.full((n, 3, 3), np.nan)
    r[finite] = so3.quat_to_matrix(quat[finite])
    movement = np.asarray(mat["movement"]).reshape(-1).astype(bool)
    truth = Truth(t, r, movement & finite)
    return SensorLog(streams, where, NAME, truth, (f"BROAD trial at {rate:g} Hz; evaluated on 'movement'",))
