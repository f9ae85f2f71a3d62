"""Recorded phone logs in, :class:`~hil.estimation.sensors.SensorLog` out: units SI, axes the body frame of
the paper
(= Android's sensor frame: x screen right, y screen up, z out of the screen), times in seconds.

Formats (``docs/formats.md``), detected from the files themselves: the project's own CSV (``csv``), a
Sensor Logger export (``sensorlogger``, folder or zip) or its JSON export (``sensorlogger-json``), a
phyphox CSV export (``phyphox``, zip or folder), a tyrex smartphone-benchmark trial folder (``tyrex``,
with motion-capture truth) and a BROAD trial ``.mat`` (``broad``, with optical truth). Any of them may
come as a folder, a zip or a tar, or an archive inside one (:mod:`hil.logs.archive`), its text in UTF-8,
UTF-16 or a legacy 8-bit encoding (:mod:`hil.logs.encoding`). A malformed file raises
:class:`InputFormatError` naming the file, line and column.
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from hil.estimation.sensors import SensorLog
from hil.files.bounded import PIPE, input_kind
from hil.logs import broad, phyphox, project_csv, sensorlogger, sensorlogger_json, tyrex
from hil.logs.table import Container
from protocol.errors import InputFormatError

READERS: dict[str, ModuleType] = {
    m.NAME: m for m in (project_csv, sensorlogger, sensorlogger_json, phyphox, tyrex, broad)
}
"""Format name → reader module (each has ``detect(container)`` and ``read(container)``)."""


def detect_format(path: Path | str) -> str:
    """The format of ``path`` (see :data:`READERS`), or InputFormatError listing what was looked for."""
    with Container(Path(path)) as container:
        return _format_of(container)


def _format_of(container: Container) -> str:
    """The format of the log ``container`` holds, or InputFormatError listing what was looked for."""
    name = _recognise(container)
    if name is not None:
        return name
    inside = logs_inside(container.path)
    hint = ""
    if any(n.lower().endswith((".json", ".json.gz")) for n in container.names()):
        hint = (
            "; a .json is read as Sensor Logger's JSON export: one array of records, "
            '[{"sensor": "Gyroscope", "time": …, "x": …}, …] (not JSON Lines, nor an object)'
        )
    if inside:
        more = f" and {len(inside) - 1} more" if len(inside) > 1 else ""
        hint = f"; it holds logs: replay one, e.g. {inside[0]}{more}"
    raise InputFormatError(
        f"not a recognised log (tried {', '.join(READERS)}; files: {', '.join(container.names()[:8])}){hint}",
        str(container.path),
    )


MAX_PROBED = 64
"""The most entries of a folder :func:`logs_inside` looks at (a folder of trials: BROAD's 39, tyrex's 20)."""


def _recognise(container: Container) -> str | None:
    """The format of the log ``container`` holds, or None."""
    return next((name for name, reader in READERS.items() if reader.detect(container)), None)


def logs_inside(folder: Path) -> list[Path]:
    """The entries of ``folder`` (the first :data:`MAX_PROBED`, by name) that are logs themselves: a folder
    of trials given where one trial was meant. Empty when ``folder`` is not a folder; an entry that cannot
    be read is passed over (the error is the folder's, not its entries')."""
    if not folder.is_dir():
        return []
    found = []
    for entry in sorted(folder.iterdir())[:MAX_PROBED]:
        try:
            if input_kind(entry, InputFormatError) == PIPE:
                continue  # reading one would wait for its writer, and use it up
            with Container(entry) as container:
                if _recognise(container) is not None:
                    found.append(entry)
        except (InputFormatError, OSError):
            continue
    return found


def read_log(path: Path | str, format: str | None = None) -> SensorLog:
    """Read a log, detecting its format unless given. The log is opened once for both: a tar, which
    is unpacked to a temporary file as it is opened (:mod:`hil.logs.archive`), is unpacked once."""
    if format is not None and format not in READERS:
        raise InputFormatError(f"unknown format {format!r} (known: {', '.join(READERS)})", str(path))
    with Container(Path(path)) as container:
        name = format or _format_of(container)
        return READERS[name].read(container)
