"""Sensor Logger exports laid out a little differently from the app's own: no ``Metadata.csv`` beside an
iOS ``AccelerometerUncalibrated.csv``, and a ``time`` re-saved as fractional epoch seconds (or ms) with no
``seconds_elapsed`` beside it.

Before: the raw accelerometer in g (which only iOS writes, in its own frames: flat, screen up, -1 g on z)
was converted to m/s^2 but not negated when no ``Metadata.csv`` stated the platform — the phone lying
screen up replayed as screen down, with no word; and a folder of the app's file names whose ``time`` was
``1679068247.609`` was taken for a phyphox export, its samples printed at 1.68e9 s. Now the first is told
to be iOS's by its unit and negated to Android's axes, noted; the second is read as Sensor Logger's, its
clock from 0 and its unit said. Built from the real Android export (read, never copied)."""

from __future__ import annotations

import json
import tempfile
import zipfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import REAL_FILES, needs_real_export, real_lines

from hil.cli import main
from hil.estimation.sensors import SensorKind
from hil.logs import detect_format, read_log

pytestmark = needs_real_export

G = 9.80665
SETTINGS = settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
METADATA_WITHOUT_PLATFORM = "version,device name,recording epoch time\n3,iPhone,1679068247375\n"
"""A ``Metadata.csv`` cut down by a tool: no ``platform`` column, so no platform stated."""


def android_acc() -> np.ndarray:
    """The real export's TotalAcceleration.csv readings as x, y, z (m/s^2, Android's axes)."""
    rows = real_lines("TotalAcceleration.csv")[1:]
    return np.array([[float(a) for a in line.split(",")[2:]] for line in rows])[:, ::-1]


def ios_raw_export(folder: Path, metadata: str | None, crlf: bool) -> Path:
    """The real export as iOS writes its raw accelerometer: ``AccelerometerUncalibrated.csv`` in g, in
    iOS's own frames (every axis negated); ``metadata`` as ``Metadata.csv`` (None: no such file)."""
    folder.mkdir(parents=True)
    end = "\r\n" if crlf else "\n"
    for name in ("Gyroscope.csv", "Magnetometer.csv"):
        (folder / name).write_bytes((end.join(real_lines(name)) + end).encode())
    total = real_lines("TotalAcceleration.csv")
    rows = [total[0]]
    for line in total[1:]:
        time, elapsed, *axes = line.split(",")
        rows.append(",".join([time, elapsed, *(repr(-float(a) / G) for a in axes)]))
    (folder / "AccelerometerUncalibrated.csv").write_bytes((end.join(rows) + end).encode())
    if metadata is not None:
        (folder / "Metadata.csv").write_text(metadata)
    return folder


@SETTINGS
@given(metadata=st.sampled_from([None, METADATA_WITHOUT_PLATFORM]), crlf=st.booleans())
def test_an_ios_raw_accelerometer_in_g_with_no_platform_stated_reads_in_androids_axes(
    tmp_path, metadata, crlf
):
    folder = ios_raw_export(Path(tempfile.mkdtemp(dir=tmp_path)) / "rec", metadata, crlf)
    log = read_log(folder)
    np.testing.assert_allclose(log.streams[SensorKind.ACC].xyz, android_acc(), rtol=1e-9, atol=1e-9)
    said = [n for n in log.notes if "which only iOS writes" in n]
    assert len(said) == 1 and "negated" in said[0] and "AccelerometerUncalibrated.csv" in said[0], log.notes


def test_hil_replay_says_it_took_the_raw_accelerometer_for_ioss(tmp_path):
    folder = ios_raw_export(tmp_path / "rec", None, False)
    out = tmp_path / "run"
    assert main(["replay", str(folder), "--out", str(out), "--no-plots"]) == 0
    notes = json.loads((out / "summary.json").read_text())["reader_notes"]
    assert any("which only iOS writes" in n and "negated" in n for n in notes), notes


def epoch_seconds_export(folder: Path, unit: str, delimiter: str, quoted: bool, zipped: bool) -> Path:
    """The real export with ``time`` re-saved as fractional epoch ``unit`` (s or ms) and no
    ``seconds_elapsed``, in ``delimiter``'s dialect (``;`` with decimal commas), cells quoted or not;
    as a folder, or zipped inside a folder one level down."""
    folder.mkdir(parents=True)
    scale = {"s": 1e-9, "ms": 1e-6}[unit]
    texts = {}
    for name in REAL_FILES:
        lines = real_lines(name)
        out = [delimiter.join(["time", *lines[0].split(",")[2:]])]
        for line in lines[1:]:
            time, _, *axes = line.split(",")
            cells = [f"{int(time) * scale:.6f}", *axes]
            if delimiter == ";":
                cells = [c.replace(".", ",") for c in cells]
            if quoted:
                cells = [f'"{c}"' for c in cells]
            out.append(delimiter.join(cells))
        texts[name] = "\n".join(out) + "\n"
    if not zipped:
        for name, text in texts.items():
            (folder / name).write_text(text)
        return folder
    path = folder.with_suffix(".zip")
    with zipfile.ZipFile(path, "w") as z:
        for name, text in texts.items():
            z.writestr(f"Recording/{name}", text)
    return path


@SETTINGS
@given(
    unit=st.sampled_from(["s", "ms"]),
    delimiter=st.sampled_from([",", ";"]),
    quoted=st.booleans(),
    zipped=st.booleans(),
)
def test_a_time_in_fractional_epoch_seconds_without_seconds_elapsed_is_read_as_sensor_loggers(
    tmp_path, unit, delimiter, quoted, zipped
):
    path = epoch_seconds_export(Path(tempfile.mkdtemp(dir=tmp_path)) / "rec", unit, delimiter, quoted, zipped)
    assert detect_format(path) == "sensorlogger"
    log = read_log(path)
    reference = read_log(
        epoch_seconds_export(Path(tempfile.mkdtemp(dir=tmp_path)) / "ns", "s", ",", False, False)
    )
    for kind, stream in log.streams.items():
        t = stream.t[np.isfinite(stream.t)]
        assert 0.0 <= t.min() and t.max() < 60.0, (kind, t.min(), t.max())  # from 0, not at 1.68e9 s
        np.testing.assert_allclose(stream.t, reference.streams[kind].t, atol=2e-6)
        np.testing.assert_allclose(stream.xyz, reference.streams[kind].xyz, rtol=1e-12)
    assert any(f"'time' in {unit} since the epoch" in n for n in log.notes), log.notes


UNITS = {"Gyroscope.csv": "rad/s", "TotalAcceleration.csv": "m/s^2", "Magnetometer.csv": "µT"}
OTHER_UNITS = {"Gyroscope.csv": ("°/s", 180 / np.pi), "TotalAcceleration.csv": ("g", 1 / G),
               "Magnetometer.csv": ("mG", 10.0)}  # fmt: skip
"""A unit each file could be written in, and the factor from the SI value to it."""


def units_row_export(
    folder: Path, delimiter: str, spelling: str, elapsed: bool, other: bool, joined: bool, row: bool = True
) -> Path:
    """The real export with a row of units under each file's header (``spelling``: ``{}``, ``({})`` or
    ``[{}]``), in ``delimiter``'s dialect; with or without ``seconds_elapsed``; the readings in SI or in
    another unit the row names (``other``); ``joined``: the file's second half as a second copy of the
    file appended (its header and units row repeated); ``row`` False: no row of units (the reference)."""
    folder.mkdir(parents=True)
    for name in REAL_FILES:
        lines = real_lines(name)
        unit, factor = OTHER_UNITS[name] if other else (UNITS[name], 1.0)
        head = lines[0].split(",")
        units = ["ns", "s", unit, unit, unit]
        rows = []
        for line in lines[1:]:
            time, seconds, *axes = line.split(",")
            rows.append([time, seconds, *(repr(float(a) * factor) for a in axes)])
        if not elapsed:
            head, units, rows = head[:1] + head[2:], units[:1] + units[2:], [r[:1] + r[2:] for r in rows]
        units = [spelling.format(u) for u in units]

        def text(cells: list[str]) -> str:
            joined_cells = delimiter.join(cells)
            return joined_cells.replace(".", ",") if delimiter == ";" else joined_cells

        block = [delimiter.join(head), delimiter.join(units)] if row else [delimiter.join(head)]
        body = [text(r) for r in rows]
        out = block + body[:150] + block + body[150:] if joined else block + body
        (folder / name).write_text("\n".join(out) + "\n", encoding="utf-8")
    return folder


@SETTINGS
@given(
    delimiter=st.sampled_from([",", ";"]),
    spelling=st.sampled_from(["{}", "({})", "[{}]"]),
    elapsed=st.booleans(),
    other=st.booleans(),
    joined=st.booleans(),
)
def test_a_row_of_units_under_the_header_is_read_as_the_headers_units(
    tmp_path, delimiter, spelling, elapsed, other, joined
):
    """Before: "'ns' is not a number", the export refused. Now the row names the columns' units, read as
    units in the header are (converted to SI), noted; the samples are the export's."""
    base = Path(tempfile.mkdtemp(dir=tmp_path))
    folder = units_row_export(base / "rec", delimiter, spelling, elapsed, other, joined)
    reference = read_log(units_row_export(base / "si", ",", "{}", elapsed, False, False, row=False))
    assert detect_format(folder) == "sensorlogger"
    log = read_log(folder)
    for kind, stream in reference.streams.items():
        np.testing.assert_array_equal(log.streams[kind].t, stream.t)
        np.testing.assert_allclose(log.streams[kind].xyz, stream.xyz, rtol=1e-9, atol=1e-12)
    said = [n for n in log.notes if "holds the columns' units" in n]
    assert len(said) == len(REAL_FILES), log.notes


def test_a_phyphox_buffer_with_a_row_of_units_reads_as_without(tmp_path):
    """phyphox custom buffers (``"time","Acceleration x"``, no units in the header) under a row of units."""
    rng = np.random.default_rng(7)
    t = 0.01 * np.arange(300)
    names = {"Acceleration": [0.1, 0.2, 9.8], "Gyroscope": [0.01, 0.0, 0.02], "Magnetic field": [20, 0, -40]}
    for with_units in (False, True):
        folder = tmp_path / ("units" if with_units else "plain")
        folder.mkdir()
        for label, mean in names.items():
            xyz = np.asarray(mean) + 0.01 * rng.standard_normal((len(t), 3))
            head = ['"time"', *(f'"{label} {a}"' for a in "xyz")]
            unit = {"Acceleration": "m/s^2", "Gyroscope": "rad/s", "Magnetic field": "µT"}[label]
            lines = [",".join(head)] + ([f'"s","{unit}","{unit}","{unit}"'] if with_units else [])
            lines += [",".join(f"{v:.9g}" for v in (ti, *row)) for ti, row in zip(t, xyz, strict=True)]
            (folder / f"{label.split()[0]}.csv").write_text("\n".join(lines) + "\n")
        rng = np.random.default_rng(7)
    plain, units = read_log(tmp_path / "plain"), read_log(tmp_path / "units")
    assert units.format == plain.format == "phyphox"
    for kind, stream in plain.streams.items():
        np.testing.assert_array_equal(units.streams[kind].t, stream.t)
        np.testing.assert_array_equal(units.streams[kind].xyz, stream.xyz)
