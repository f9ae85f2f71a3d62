"""Numeric text tables (CSV and friends) read fast, with errors that say file, line and column.

The fast path hands the whole text to ``numpy.loadtxt``; only if that fails is the text walked line by
line to find the first bad cell and raise :class:`InputFormatError` naming it. ``nan``/``NaN`` cells are
numbers (NaN samples, counted and dropped later by the merge); anything else unparseable is an error.
"""

from __future__ import annotations

import gzip
import io
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from protocol.errors import InputFormatError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Table:
    """Parsed rows: ``data`` (N, C) floats under ``columns`` (C header names, stripped and unquoted;
    ``col0``… without a header); ``source`` names the file for messages."""

    columns: tuple[str, ...]
    data: Array
    source: str

    def column(self, name: str) -> Array:
        try:
            return self.data[:, self.columns.index(name)]
        except ValueError:
            raise InputFormatError(
                f"no column {name!r} (columns: {', '.join(self.columns)})", self.source
            ) from None


class Container:
    """Files of a log: a directory, a zip archive, or a single file. ``names()`` lists member file names
    (base names); ``text(name)`` reads one (``.gz`` members decompressed); ``where(name)`` says where."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise InputFormatError("no such file or directory", str(self.path))
        self._zip = zipfile.ZipFile(self.path) if zipfile.is_zipfile(self.path) else None
        if self._zip is not None:
            self._members = {Path(n).name: n for n in self._zip.namelist() if not n.endswith("/")}
        elif self.path.is_dir():
            self._members = {p.name: str(p) for p in sorted(self.path.iterdir()) if p.is_file()}
        else:
            self._members = {self.path.name: str(self.path)}

    def names(self) -> list[str]:
        return list(self._members)

    def has(self, name: str) -> bool:
        return name in self._members

    def where(self, name: str) -> str:
        return (
            f"{self.path}:{name}" if self._zip is not None else self._members.get(name, str(self.path / name))
        )

    def raw(self, name: str) -> bytes:
        if name not in self._members:
            raise InputFormatError(f"missing {name}", str(self.path))
        if self._zip is not None:
            data = self._zip.read(self._members[name])
        else:
            data = Path(self._members[name]).read_bytes()
        return gzip.decompress(data) if name.endswith(".gz") else data

    def text(self, name: str) -> str:
        data = self.raw(name)
        try:
            return data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise InputFormatError(
                f"not UTF-8 text ({exc.reason} at byte {exc.start})", self.where(name)
            ) from None


def parse_table(
    text: str,
    source: str,
    delimiter: str | None = ",",
    header: bool = True,
    decimal_comma: bool = False,
    min_columns: int = 1,
) -> Table:
    """Parse a numeric table. ``delimiter`` None means runs of whitespace; ``decimal_comma`` for
    exports such as phyphox's "semicolon, decimal comma" CSV. Lines starting with ``#`` are comments;
    blank lines are skipped. Every data row must have as many cells as the header (or the first row)."""
    lines = text.splitlines()
    first = 0
    while first < len(lines) and (not lines[first].strip() or lines[first].lstrip().startswith("#")):
        first += 1
    if first == len(lines):
        raise InputFormatError("empty file: no header and no data", source)
    if header:
        columns = tuple(c.strip().strip('"').strip() for c in _split(lines[first], delimiter))
        first += 1
    else:
        width = len(_split(lines[first], delimiter))
        columns = tuple(f"col{i}" for i in range(width))
    if len(columns) < min_columns:
        raise InputFormatError(
            f"expected at least {min_columns} columns, found {len(columns)}", source, first
        )
    body = "\n".join(lines[first:])
    if decimal_comma:
        body = body.replace(",", ".")
    try:
        data = np.loadtxt(io.StringIO(body), delimiter=delimiter, comments="#", ndmin=2, dtype=float)
        if data.size == 0:
            data = np.zeros((0, len(columns)))
        if data.shape[1] != len(columns):
            raise ValueError("column count")
    except ValueError:
        _locate_error(lines, first, columns, delimiter, decimal_comma, source)
        raise InputFormatError("unparseable table", source) from None  # _locate_error always raises
    return Table(columns, data, source)


def _split(line: str, delimiter: str | None) -> list[str]:
    return line.split(delimiter) if delimiter is not None else line.split()


def _locate_error(
    lines: list[str],
    first: int,
    columns: tuple[str, ...],
    delimiter: str | None,
    decimal_comma: bool,
    source: str,
) -> None:
    """Walk the rows and raise InputFormatError at the first bad one (1-based line numbers)."""
    for i in range(first, len(lines)):
        line = lines[i]
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        cells = _split(line.rstrip("\r"), delimiter)
        if len(cells) != len(columns):
            raise InputFormatError(f"{len(cells)} values, expected {len(columns)}", source, i + 1)
        for name, cell in zip(columns, cells, strict=True):
            value = cell.strip().strip('"')
            try:
                float(value.replace(",", ".") if decimal_comma else value)
            except ValueError:
                what = f"{value!r} is not a number" if value else "empty value"
                raise InputFormatError(what, source, i + 1, name) from None
    raise InputFormatError("unparseable table (no single bad cell found)", source)
