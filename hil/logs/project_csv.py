"""The project's own sensor-log CSV (specified in docs/formats.md): one long table, every sensor's samples
in their own rows, so mismatched rates need no resampling; optional ground-truth rows.

::

    # vscmg-hil sensor log v1
    # units: t_s s; gyr rad/s; acc m/s^2 (gravity included); mag uT; truth: quaternion body->ENU
    t_s,sensor,x,y,z,w
    0.000000,gyr,0.0100,-0.0200,0.0030,
    0.002100,acc,0.1200,0.2000,9.7900,
    0.004700,mag,1.2000,28.7000,-37.0000,
    0.000000,truth,0.0,0.0,0.0,1.0

The six columns are found by name, in any order; a column a tool added beside them is never parsed
(:mod:`hil.logs.rows`). A spreadsheet's re-save — semicolons or tabs, decimal commas, quoted cells — is read
in its own dialect (:func:`~hil.logs.table.sniff_dialect`, as every CSV reader). ``sensor`` is ``gyr``,
``acc``, ``mag`` or ``truth``. Sensor rows leave ``w`` empty; truth rows hold a unit quaternion with vector
part ``x, y, z`` and scalar part ``w``. Axes are the body frame (x screen right, y screen up, z out of the
screen); truth is body → ENU. Rows need not be sorted across sensors; each sensor's own rows keep their order
(the merge drops and counts any that go backwards). ``nan`` values are allowed (NaN samples, counted and
dropped by the merge); other unparseable cells are errors with file, line and column.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hil import so3
from hil.estimation.sensors import KINDS, SensorKind, SensorLog, SensorStream, Truth
from hil.logs.rows import BadCell, is_content, number, shown
from hil.logs.sensorlogger import SAMPLE_STEP_S
from hil.logs.table import (
    Container,
    Header,
    content_head,
    read_table,
    sniff_dialect,
    split_header,
    text_lines,
)
from protocol.errors import InputFormatError

NAME = "csv"
MAGIC = "# vscmg-hil sensor log v1"
HEADER = "t_s,sensor,x,y,z,w"
_CODES = {k.label: float(int(k)) for k in KINDS} | {"truth": 3.0}
_COLUMNS = HEADER.split(",")


def detect(c: Container) -> bool:
    names = c.names()
    if len(names) != 1 or not names[0].lower().endswith((".csv", ".csv.gz")):  # gzipped: read decompressed
        return False
    head = c.head(names[0], 1)
    if head and head[0].startswith(MAGIC):
        return True
    content = content_head(c, names[0], 2)  # the header, past the comment and blank lines before it
    return bool(content) and _is_header(content[0], sniff_dialect(content)[0])


def _is_header(line: str, delimiter: str) -> bool:
    """Whether a line is this format's header: its six names, among others a tool may have added."""
    return set(_COLUMNS) <= set(split_header(line, delimiter))


def read(c: Container) -> SensorLog:
    name = c.names()[0]
    where = c.where(name)
    converters = {"sensor": _sensor_code, "w": _w}
    # the file's own dialect (hil.logs.table.sniff_dialect, as every CSV reader): a spreadsheet's re-save
    # with semicolons (or tabs) and decimal commas was refused, "expected header 't_s,sensor,…'"
    delimiter, decimal_comma = sniff_dialect(content_head(c, name, 2))
    table = read_table(c, name, delimiter, decimal_comma=decimal_comma, use=_columns, converters=converters)
    data = table.data  # the columns in the header's order, whatever the file's
    streams = {}
    for kind in KINDS:
        rows = data[data[:, 1] == int(kind)]
        if len(rows) or kind is not SensorKind.MAG:  # no magnetometer rows: a 6-axis log
            streams[kind] = SensorStream(kind, rows[:, 0], rows[:, 2:5])
    for stream in streams.values():
        check_seconds(stream, where)
    truth_rows = data[data[:, 1] == 3]
    truth = None
    if len(truth_rows):
        quat = truth_rows[:, [5, 2, 3, 4]]
        bad = ~(np.abs(np.linalg.norm(quat, axis=1) - 1.0) < 1e-3)
        if bad.any():
            row = int(np.flatnonzero(data[:, 1] == 3)[np.argmax(bad)])
            line = _line_of_row(c, name, row, table.repeated_headers)
            raise InputFormatError("truth quaternion is not of unit norm", where, line, "w")
        order = np.argsort(truth_rows[:, 0], kind="stable")
        truth = Truth(truth_rows[order, 0], so3.quat_to_matrix(quat[order]))
    return SensorLog(streams, where, NAME, truth, ("project CSV v1", *table.layout_notes()))


SLOWEST_STEP_S = 1.5 * SAMPLE_STEP_S[1]
"""s: the median step between a sensor's samples above which ``t_s`` is taken for no seconds: a phone
sensor samples at 1 Hz or faster (:data:`~hil.logs.sensorlogger.SAMPLE_STEP_S`), and a 1 Hz sensor's
median step is 1 s give or take its jitter (half of it here); a time in ms is 1 000 times its step in s
(a 600 Hz sensor's 1.7), in ns 10⁹ times."""
MIN_STEPS = 10
"""Steps a sensor needs before its median step is judged (a few rows either side of a gap say little)."""


def check_seconds(stream: SensorStream, where: str, column: str = "t_s") -> None:
    """An :class:`InputFormatError` naming ``where`` and the time ``column`` when a sensor's samples lie a
    median step apart that no phone sensor's do (:data:`SLOWEST_STEP_S`): a time in ms or ns written
    where seconds go (this format's ``t_s``, a tyrex file's first column). Read as seconds, ns since the
    epoch put each sample 10⁷ s from the next, every one a part of its own, and the replay said only that
    no part had every sensor speaking (a tyrex gyroscope in ms: that the magnetometer gave no direction)."""
    t = stream.t[np.isfinite(stream.t)]
    steps = np.diff(t)
    steps = steps[steps > 0]
    if len(steps) < MIN_STEPS:
        return
    step = float(np.median(steps))
    if step > SLOWEST_STEP_S:
        raise InputFormatError(
            f"the {stream.kind.label} rows lie a median {step:.6g} s apart: no phone sensor samples more "
            f"than {SAMPLE_STEP_S[1]:g} s apart; {column} is in seconds (a time in ms or ns written there?)",
            where,
            None,
            column,
        )


def _columns(header: Header) -> tuple[str, ...]:
    """The six columns, found by name: a column a tool added beside them is never parsed."""
    if not set(_COLUMNS) <= set(header.columns):
        found = ",".join(header.columns)
        raise InputFormatError(f"expected header {HEADER!r}, found {found!r}", header.source, header.line)
    return tuple(_COLUMNS)


def _sensor_code(cell: str) -> float:
    code = _CODES.get(cell.strip())
    if code is None:
        raise BadCell(f"unknown sensor {shown(cell.strip())} (gyr, acc, mag or truth)")
    return code


def _w(cell: str) -> float:
    """``w``: empty on a sensor row (NaN; a truth row's NaN fails its unit-norm check)."""
    return number(cell.strip()) if cell.strip() else math.nan


def _line_of_row(c: Container, name: str, row: int, repeated: tuple[int, ...] = ()) -> int:
    """1-based file line of data row ``row`` (comments, blank lines, the header and the ``repeated`` lines
    that repeat it skipped), streamed."""
    seen = -2  # the header is the first non-comment line
    skip = set(repeated)
    for first, lines in text_lines(c, name):
        for i, line in enumerate(lines):
            if is_content(line) and first + i not in skip:
                seen += 1
                if seen == row:
                    return first + i
    return 0


def write(log: SensorLog, path: Path | str) -> Path:
    """Write ``log`` (and its truth, if any) in this format, rows in time order (stable per sensor);
    times to the nanosecond, values to 10 significant digits."""
    path = Path(path)
    blocks = []
    for kind in log.kinds:
        s = log.streams[kind]
        blocks.append((s.t, np.full(len(s), int(kind)), s.xyz, np.full(len(s), np.nan)))
    if log.truth is not None:
        q = so3.matrix_to_quat(log.truth.R)
        blocks.append((log.truth.t, np.full(len(log.truth), 3), q[:, 1:], q[:, 0]))
    t = np.concatenate([b[0] for b in blocks])
    code = np.concatenate([b[1] for b in blocks])
    xyz = np.concatenate([b[2] for b in blocks])
    w = np.concatenate([b[3] for b in blocks])
    order = np.argsort(t, kind="stable")
    names = {int(k): k.label for k in KINDS} | {3: "truth"}
    with path.open("w", encoding="utf-8", newline="\n") as f:
        f.write(f"{MAGIC}\n# source: {log.source} ({log.format})\n")
        f.write(
            "# units: t_s s; gyr rad/s; acc m/s^2 (gravity included); mag uT; truth: quaternion body->ENU\n"
        )
        f.write(HEADER + "\n")
        cols = (t[order].tolist(), code[order].tolist(), xyz[order].tolist(), w[order].tolist())
        rows = zip(*cols, strict=True)
        for ti, ci, (x, y, z), wi in rows:
            wv = "" if math.isnan(wi) else f"{wi:.10g}"
            f.write(f"{ti:.9f},{names[int(ci)]},{x:.10g},{y:.10g},{z:.10g},{wv}\n")
    return path
