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
        _only_one_log(container)
        _no_json_export_beside(container, name)
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
    packed = next(
        ((n, ext) for n in container.names()[:20] if (ext := container.packed_as(n)) is not None), None
    )
    if packed is not None:  # a gzip file named .csv was only "not a recognised log"
        name, ext = packed
        if name.lower().endswith(ext):  # Gyroscope.csv.xz was told to be named Gyroscope.csv.xz.xz
            hint += f"; {name} is {ext} data, which is not read compressed: decompress it first (a .gz is)"
        else:
            readable = "the reader opens it so named" if ext in (".gz", ".zip") else "decompress it first"
            hint += (
                f"; {name} is {ext} data under a name that does not say so: name it {name}{ext} ({readable})"
            )
    raise InputFormatError(
        f"not a recognised log (tried {', '.join(READERS)}; files: {', '.join(container.names()[:8])}){hint}",
        str(container.path),
    )


MAX_PROBED = 64
"""The most entries of a folder :func:`logs_inside` looks at (a folder of trials: BROAD's 39, tyrex's 20)."""


def _recognise(container: Container) -> str | None:
    """The format of the log ``container`` holds, or None."""
    return next((name for name, reader in READERS.items() if reader.detect(container)), None)


def logs_inside(folder: Path, depth: int = 1) -> list[Path]:
    """The entries of ``folder`` (the first :data:`MAX_PROBED`, by name) that are logs themselves: a folder
    of trials given where one trial was meant; with ``depth`` > 1 also those in its sub-folders that are no
    log, that many levels down. Empty when ``folder`` is not a folder; an entry that cannot be read is
    passed over (the error is the folder's, not its entries')."""
    return [path for path, _ in _logs_found(folder, depth, [MAX_PROBED])]


def _logs_found(folder: Path, depth: int, budget: list[int]) -> list[tuple[Path, str]]:
    """(entry, its format) of :func:`logs_inside`; ``budget`` the entries that may still be looked at."""
    if not folder.is_dir():
        return []
    found: list[tuple[Path, str]] = []
    for entry in sorted(folder.iterdir()):
        if budget[0] <= 0:
            break
        budget[0] -= 1
        try:
            if input_kind(entry, InputFormatError) == PIPE:
                continue  # reading one would wait for its writer, and use it up
            with Container(entry) as container:
                name = _recognise(container)
        except (InputFormatError, OSError):
            continue
        if name is not None:
            found.append((entry, name))
        elif depth > 1 and entry.is_dir():
            found += _logs_found(entry, depth - 1, budget)
    return found


BENEATH = 2
"""Levels of sub-folders :func:`_only_one_log` looks for logs in (``data/broad/01.mat`` beside
``data/sensorlogger-android/``)."""


def _only_one_log(container: Container) -> None:
    """An InputFormatError listing them when the folder ``container`` holds logs of more than one format in
    its sub-folders and archives (a Sensor Logger export beside tyrex trials and a BROAD ``.mat``): a
    reader finds its own files among the others, and the folder replayed one of its logs, exit 0, the
    others passed over without a word. Logs of one format are the reader's to read together (phyphox's
    single-sensor exports) or refuse (Sensor Logger exports side by side). A folder whose files all lie at
    its top (an export, a trial) is not looked into."""
    if not container.path.is_dir() or not any("/" in name for name in container.names()):
        return
    by_format: dict[str, list[Path]] = {}
    for path, name in _logs_found(container.path, BENEATH, [MAX_PROBED]):
        by_format.setdefault(name, []).append(path)
    if len(by_format) < 2:
        return
    listed = "; ".join(
        f"{name}: {paths[0]}" + (f" and {len(paths) - 1} more" if len(paths) > 1 else "")
        for name, paths in sorted(by_format.items())
    )
    raise InputFormatError(
        f"logs of different formats in one folder ({listed}): it holds logs: replay one",
        str(container.path),
    )


def _no_json_export_beside(container: Container, name: str) -> None:
    """An InputFormatError when a Sensor Logger JSON export lies beside a log of another format in
    ``container`` (a recording's CSV files, a phyphox export, and a ``.json`` export in one folder or
    zip): two logs side by side, as two recordings of one format are (replay one). The JSON export is
    read by no other reader and reads no other's files, so whichever :data:`READERS` told first was read
    and the other passed over without a word — another recording's, as like as not. ``--format``
    chooses one and skips this."""
    json_name = sensorlogger_json.NAME
    if name == json_name:
        others = [n for n, reader in READERS.items() if n != json_name and reader.detect(container)]
        other = others[0] if others else None
    else:
        other = name if sensorlogger_json.detect(container) else None
    if other is not None:
        beside = ", ".join(sensorlogger_json.exports(container)[:4])
        raise InputFormatError(
            f"a Sensor Logger JSON export ({beside}) beside a {other} log: two logs side by side; replay "
            f"one (the JSON file itself, or choose with --format {other} or --format {json_name})",
            str(container.path),
        )


def read_log(path: Path | str, format: str | None = None) -> SensorLog:
    """Read a log, detecting its format unless given. The log is opened once for both: a tar, which
    is unpacked to a temporary file as it is opened (:mod:`hil.logs.archive`), is unpacked once."""
    if format is not None and format not in READERS:
        raise InputFormatError(f"unknown format {format!r} (known: {', '.join(READERS)})", str(path))
    with Container(Path(path)) as container:
        name = format or _format_of(container)
        return READERS[name].read(container)
