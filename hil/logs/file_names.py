"""Which of a log's files a warning about one sensor names: a folder export's notes say which file each
sensor was read from (``Gyroscope.csv``, ``TotalAcceleration.csv``), and a unit warning points at the one
to fix (:mod:`hil.logs.gyro_units`, :mod:`hil.logs.acc_units`)."""

from __future__ import annotations

import re

from hil.estimation.sensors import SensorLog


def sensor_files_where(log: SensorLog, stem: str) -> str:
    """The log's source, and in brackets every file its notes name whose name holds ``stem`` (a regex
    fragment, e.g. ``"[Gg]yro"``): ``"rec/ (Gyroscope.csv)"``; the source alone when no note names one."""
    pattern = rf"[^\s:'\"(),]*{stem}[^\s:'\"(),]*\.\w+"
    files = sorted({name for note in log.notes for name in re.findall(pattern, note)})
    return f"{log.source} ({', '.join(files)})" if files else log.source
