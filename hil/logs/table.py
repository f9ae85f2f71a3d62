"""Numeric text tables (CSV and friends) read as a stream, with errors that say file, line and column.

A table is read in chunks of :data:`CHUNK_BYTES` of lines: each chunk goes to ``numpy.loadtxt`` and only the
parsed floats are kept, so memory is bounded by the samples kept (not by the file's size), and a bad line
fails as soon as its chunk is parsed — the rest of the file is never read. When a chunk fails, its lines
are walked to raise :class:`InputFormatError` naming the first bad cell. ``nan``/``NaN`` cells are numbers
(NaN samples, counted and dropped later by the merge); anything else unparseable is an error.
"""

from __future__ import annotations

import csv
import gzip
import io
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from protocol.errors import InputFormatError

Array = NDArray[np.float64]
CHUNK_BYTES = 1 << 20
"""Text parsed at once (about 20 000 lines): the most a reader holds as text, and how far past a bad line
it can have read."""
HEAD_BYTES = 4096


@dataclass(frozen=True)
class Table:
    """Parsed rows: ``data`` (N, C) floats under ``columns`` (C header names, stripped and unquoted;
    ``col0``… without a header); ``source`` names the file for messages; ``header_line`` is the 1-based
    line of the header (0 without one); ``exact`` holds the columns read as exact int64 on request."""

    columns: tuple[str, ...]
    data: Array
    source: str
    header_line: int = 0
    exact: Mapping[str, NDArray[np.int64]] = field(default_factory=dict)

    def column(self, name: str) -> Array:
        try:
            return self.data[:, self.columns.index(name)]
        except ValueError:
            raise InputFormatError(
                f"no column {name!r} (columns: {', '.join(self.columns)})",
                self.source,
                self.header_line or None,
            ) from None


class Container:
    """Files of a log: a directory, a zip archive, or a single file. ``names()`` lists member file names
    (paths relative to the container, '/'-separated); ``open_text(name)`` streams one (``.gz`` members
    decompressed), ``head(name)`` gives its first lines, ``where(name)`` says where it is."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise InputFormatError("no such file or directory", str(self.path))
        # name -> (the zip archive holding it or None, the path inside it or on disk)
        self._members: dict[str, tuple[zipfile.ZipFile | None, str]] = {}
        self._zips: list[zipfile.ZipFile] = []
        if zipfile.is_zipfile(self.path):
            self._add_zip(self.path, "")
        elif self.path.is_dir():
            for p in sorted(q for q in self.path.rglob("*") if q.is_file()):
                rel = p.relative_to(self.path).as_posix()
                if p.suffix.lower() == ".zip" and zipfile.is_zipfile(p):
                    self._add_zip(p, rel.removesuffix(p.suffix) + "/")  # an export zip inside a folder
                else:
                    self._members[rel] = (None, str(p))
        else:
            self._members[self.path.name] = (None, str(self.path))

    def _add_zip(self, path: Path, prefix: str) -> None:
        archive = zipfile.ZipFile(path)
        self._zips.append(archive)
        members = [n for n in archive.namelist() if not n.endswith("/")]
        for n in members:
            self._members[prefix + _relative(n, members)] = (archive, n)

    def names(self) -> list[str]:
        return list(self._members)

    def has(self, name: str) -> bool:
        return name in self._members

    def where(self, name: str) -> str:
        archive, inner = self._members.get(name, (None, str(self.path / name)))
        return f"{archive.filename}:{inner}" if archive is not None else inner

    def _open(self, name: str) -> IO[bytes]:
        if name not in self._members:
            raise InputFormatError(f"missing {name}", str(self.path))
        archive, inner = self._members[name]
        raw: IO[bytes] = archive.open(inner) if archive is not None else open(inner, "rb")  # noqa: SIM115
        return gzip.GzipFile(fileobj=raw) if name.endswith(".gz") else raw  # type: ignore[return-value]

    def raw(self, name: str) -> bytes:
        with self._open(name) as f:
            return f.read()

    def open_text(self, name: str) -> io.TextIOWrapper:
        """The member as UTF-8 text, streamed (a BOM is skipped); close it (``with``)."""
        return io.TextIOWrapper(self._open(name), encoding="utf-8-sig", newline=None)

    def head(self, name: str, lines: int = 3) -> list[str]:
        """The first ``lines`` lines (of at most :data:`HEAD_BYTES` bytes), decoded leniently: enough to
        recognise a format without reading the file."""
        with self._open(name) as f:
            data = f.read(HEAD_BYTES)
        return data.decode("utf-8-sig", "replace").splitlines()[:lines]

    def text(self, name: str) -> str:
        """A small member whole (metadata files): UTF-8 or InputFormatError naming it."""
        data = self.raw(name)
        try:
            return data.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise InputFormatError(
                f"not UTF-8 text ({exc.reason} at byte {exc.start})", self.where(name)
            ) from None


def _relative(member: str, members: Sequence[str]) -> str:
    """A zip member's name without the one folder every member shares (exports zip their folder)."""
    tops = {m.split("/", 1)[0] for m in members}
    if len(tops) == 1 and all("/" in m for m in members):
        return member.split("/", 1)[1]
    return member


def split_header(line: str, delimiter: str | None) -> list[str]:
    """Header cells, quotes removed (``"Time (s)","Acceleration x (m/s^2)"``)."""
    if delimiter is None:
        return [c.strip('"') for c in line.split()]
    return [c.strip().strip('"').strip() for c in next(csv.reader([line], delimiter=delimiter))]


Locate = Callable[[Sequence[tuple[int, str]], tuple[str, ...], str], None]
"""Walks a failed chunk's ``(line number, text)`` pairs (with the columns and the source) and raises
naming the bad cell."""


def read_table(
    container: Container,
    name: str,
    delimiter: str | None = ",",
    header: bool = True,
    decimal_comma: bool = False,
    min_columns: int = 1,
    exact_columns: Sequence[str] = (),
    converters: Mapping[int, Callable[[str], float]] | None = None,
    locate: Locate | None = None,
) -> Table:
    """Stream one member of ``container`` into a :class:`Table` (see the module docstring).

    ``delimiter`` None means runs of whitespace; ``decimal_comma`` for exports such as phyphox's
    "semicolon/tab, decimal comma" CSV. Lines starting with ``#`` are comments; blank lines are skipped.
    Every data row must have as many cells as the header (or the first row). ``exact_columns`` are also
    read as int64 (e.g. nanosecond epoch times, which float64 rounds to 256 ns); ``converters`` and
    ``locate`` let a reader parse non-numeric cells and explain their errors."""
    source = container.where(name)
    with container.open_text(name) as f:
        try:
            line_no, head = _first_line(f)
            if not head:
                raise InputFormatError("empty file: no header and no data", source)
            if header:
                columns, header_line = tuple(split_header(head, delimiter)), line_no
            else:
                columns, header_line = tuple(f"col{i}" for i in range(len(_split(head, delimiter)))), 0
            if len(columns) < min_columns:
                raise InputFormatError(
                    f"expected at least {min_columns} columns, found {len(columns)}: is this the right file?",
                    source,
                    header_line or 1,
                )
            exact_idx = tuple((c, columns.index(c)) for c in exact_columns if c in columns)
            parser = _Chunks(columns, source, delimiter, decimal_comma, converters, locate, exact_idx)
            if not header:
                parser.parse([head + "\n"], line_no)
            while chunk := f.readlines(CHUNK_BYTES):
                parser.parse(chunk, line_no + 1)
                line_no += len(chunk)
        except UnicodeDecodeError as exc:
            bad = _undecodable_line(container, name)
            raise InputFormatError(f"not UTF-8 text ({exc.reason})", source, bad) from None
    return parser.table(header_line)


def _first_line(f: io.TextIOWrapper) -> tuple[int, str]:
    """The first line that is neither blank nor a comment, and its 1-based number ("" at the end)."""
    line_no = 0
    for line_no, line in enumerate(iter(f.readline, ""), 1):  # noqa: B007
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            return line_no, line.rstrip("\r\n")
    return line_no, ""


def _undecodable_line(container: Container, name: str) -> int:
    """The 1-based number of the first line that is not UTF-8 (the error path only)."""
    with container._open(name) as raw:
        for line_no, line in enumerate(raw, 1):
            try:
                line.decode("utf-8-sig" if line_no == 1 else "utf-8")
            except UnicodeDecodeError:
                return line_no
    return 0


def _split(line: str, delimiter: str | None) -> list[str]:
    return line.split(delimiter) if delimiter is not None else line.split()


@dataclass
class _Chunks:
    """Parses chunks of numbered lines into float arrays (and exact int64 columns), keeping only those."""

    columns: tuple[str, ...]
    source: str
    delimiter: str | None
    decimal_comma: bool
    converters: Mapping[int, Callable[[str], float]] | None
    locate: Locate | None
    exact_idx: tuple[tuple[str, int], ...]
    chunks: list[Array] = field(default_factory=list)
    exact: dict[str, list[NDArray[np.int64]]] = field(default_factory=dict)

    def parse(self, lines: list[str], first_line: int) -> None:
        """Parse ``lines`` (raw, with their newlines), the first of which is line ``first_line``."""
        text = "".join(lines)
        if self.decimal_comma:
            text = text.replace(",", ".")
        try:
            converters: Any = self.converters
            data = np.loadtxt(io.StringIO(text), delimiter=self.delimiter, ndmin=2, dtype=float,
                              comments="#", converters=converters, quotechar='"')  # fmt: skip
            if data.size == 0:
                return  # only blank lines and comments
            if data.shape[1] != len(self.columns):
                raise ValueError("column count")
        except (ValueError, KeyError):
            pending = [(first_line + i, line.rstrip("\r\n")) for i, line in enumerate(lines)
                       if line.strip() and not line.lstrip().startswith("#")]  # fmt: skip
            if self.locate is not None:
                self.locate(pending, self.columns, self.source)
            locate_numeric(pending, self.columns, self.source, self.delimiter, self.decimal_comma)
            raise InputFormatError("unparseable table (no single bad cell found)", self.source) from None
        self.chunks.append(data)
        for col, idx in self.exact_idx:
            try:
                ints = np.loadtxt(io.StringIO(text), delimiter=self.delimiter, usecols=idx, dtype=np.int64,
                                  ndmin=1, comments="#", quotechar='"')  # fmt: skip
            except ValueError:  # not integers (a re-saved file): the float column, to its precision
                ints = data[:, idx].astype(np.int64)
            self.exact.setdefault(col, []).append(ints)

    def table(self, header_line: int) -> Table:
        data = np.concatenate(self.chunks) if self.chunks else np.zeros((0, len(self.columns)))
        exact = {c: np.concatenate(self.exact[c]) if c in self.exact else np.zeros(0, np.int64)
                 for c, _ in self.exact_idx}  # fmt: skip
        return Table(self.columns, data, self.source, header_line, exact)


def locate_numeric(
    pending: Sequence[tuple[int, str]],
    columns: tuple[str, ...],
    source: str,
    delimiter: str | None,
    decimal_comma: bool,
) -> None:
    """Raise InputFormatError at the first bad row or cell of ``pending`` (all cells numbers)."""
    for line_no, line in pending:
        cells = _split(line, delimiter)
        if len(cells) != len(columns):
            raise InputFormatError(f"{len(cells)} values, expected {len(columns)}", source, line_no)
        for name, cell in zip(columns, cells, strict=True):
            value = cell.strip().strip('"')
            try:
                float(value.replace(",", ".") if decimal_comma else value)
            except ValueError:
                what = f"{value!r} is not a number" if value else "empty value"
                raise InputFormatError(what, source, line_no, name) from None
