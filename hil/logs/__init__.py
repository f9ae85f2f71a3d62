"""Recorded phone logs in, :class:`~hil.estimation.sensors.SensorLog` out: units SI, axes the body frame of
the paper
(= Android's sensor frame: x screen right, y screen up, z out of the screen), times in seconds.

Formats (``docs/formats.md``), detected from the files themselves: the project's own CSV (``csv``), a
Sensor Logger export (``sensorlogger``, folder or zip), a phyphox CSV export (``phyphox``, zip or folder),
a tyrex smartphone-benchmark trial folder (``tyrex``, with motion-capture truth) and a BROAD trial
``.mat`` (``broad``, with optical truth). A malformed file raises :class:`InputFormatError` naming the
file, line and column.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from hil.estimation.sensors import SensorLog
from hil.logs import broad, phyphox, project_csv, sensorlogger, tyrex
from hil.logs.table import Container
from protocol.errors import InputFormatError

READERS: dict[str, ModuleType] = {m.NAME: m for m in (project_csv, sensorlogger, phyphox, tyrex, broad)}
"""Format name → reader module (each has ``detect(container)`` and ``read(container)``)."""


def detect_format(path: Path | str) -> str:
    """The format of ``path`` (see :data:`READERS`), or InputFormatError listing what was looked for."""
    container = Container(Path(path))
    for name, reader in READERS.items():
        if reader.detect(container):
            return name
    raise InputFormatError(
        f"not a recognised log (tried {', '.join(READERS)}; files: {', '.join(container.names()[:8])})",
        str(path),
    )


def read_log(path: Path | str, format: str | None = None) -> SensorLog:
    """Read a log, detecting its format unless given."""
    if format is not None and format not in READERS:
        raise InputFormatError(f"unknown format {format!r} (known: {', '.join(READERS)})", str(path))
    name = format or detect_format(path)
    return READERS[name].read(Container(Path(path)))
