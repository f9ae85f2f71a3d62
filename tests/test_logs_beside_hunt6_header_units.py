"""Phone exports whose header names their units in another app's or tool's spelling (a hunt's finding):
the real Sensor Logger export of ``../shared/data``, its readings rewritten in a unit its header names —
the field in gauss (``z (G)``) or milligauss (``mG``), the acceleration in milli-g (``mg``), the rate in
``dps`` or ``mrad/s``.

Each was refused, "unknown unit 'g' for the mag", though the header says exactly what its numbers are.
Each is now read to the same samples as the export in SI units; a unit still unknown stays a typed error
naming the file, its header line and the column.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import needs_real_export, real_export

from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from protocol.errors import InputFormatError

pytestmark = needs_real_export
FILES = {
    SensorKind.GYR: "Gyroscope.csv",
    SensorKind.ACC: "TotalAcceleration.csv",
    SensorKind.MAG: "Magnetometer.csv",
}
UNITS_OF_OTHER_APPS = [  # (sensor, unit as written, SI units per one of it)
    (SensorKind.MAG, "G", 100.0),
    (SensorKind.MAG, "gauss", 100.0),
    (SensorKind.MAG, "mG", 0.1),
    (SensorKind.ACC, "mg", 9.80665e-3),
    (SensorKind.ACC, "g", 9.80665),
    (SensorKind.GYR, "dps", math.pi / 180),
    (SensorKind.GYR, "mrad/s", 1e-3),
]


def in_unit(kind: SensorKind, unit: str, si_per_unit: float, brackets: bool):
    """An edit for :func:`real_export`: ``kind``'s file with its readings in ``unit`` and the unit in its
    header's axis cells (in parentheses or brackets)."""

    def edit(name: str, lines: list[str]) -> list[str]:
        if name != FILES[kind]:
            return lines
        cells = lines[0].split(",")
        mark = f"[{unit}]" if brackets else f"({unit})"
        header = ",".join(cells[:2] + [f"{c} {mark}" for c in cells[2:]])
        rows = []
        for line in lines[1:]:
            c = line.split(",")
            rows.append(",".join(c[:2] + [repr(float(v) / si_per_unit) for v in c[2:]]))
        return [header, *rows]

    return edit


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=st.sampled_from(UNITS_OF_OTHER_APPS), brackets=st.booleans())
def test_a_unit_the_header_names_is_read_in_si(
    tmp_path: Path, case: tuple[SensorKind, str, float], brackets: bool
) -> None:
    kind, unit, si_per_unit = case
    reference = read_log(real_export(tmp_path / "si"))
    folder = real_export(
        tmp_path / f"{kind.label}-{unit.replace('/', '_')}-{brackets}", in_unit(*case, brackets)
    )
    log = read_log(folder)
    for k, stream in reference.streams.items():
        np.testing.assert_array_equal(log.streams[k].t, stream.t)
        np.testing.assert_allclose(log.streams[k].xyz, stream.xyz, rtol=1e-12, atol=1e-12)


def test_a_unit_still_unknown_is_refused_naming_file_line_and_column(tmp_path: Path) -> None:
    folder = real_export(tmp_path / "furlongs", in_unit(SensorKind.MAG, "Oe/fortnight", 3.0, False))
    with pytest.raises(InputFormatError) as refused:
        read_log(folder)
    said = str(refused.value)
    assert "Magnetometer.csv:1" in said and "oe/fortnight" in said.lower()
