"""A text table's rows parsed a chunk at a time into floats: only the columns its reader uses.

A phone's export often carries columns no reader needs — an ``accuracy`` of ``HIGH``, an ``activity``
label, a device name, empty cells, a quoted note with commas in it. Only the columns a reader names
(:class:`RowParser` ``used``) must hold numbers; every other cell is never parsed (``numpy.loadtxt``
``usecols``), so nothing in it can stop the read. What still must hold for every row, used cells or not:

- it has exactly as many cells as the header (or, without one, the first row). A row with more cells
  cannot say which of them is extra: every column after it could be shifted, so a used column could read
  another's values. It is an :class:`InputFormatError` naming its line, as is a row with fewer cells;
- a cell is split as a CSV cell is: a quoted cell may hold the delimiter (``"walk, then run"``) and
  doubled quotes; a space before its opening quote is allowed. A cell cannot hold a line break (a note
  over two lines is two rows of too few cells, an error naming the first). Runs of whitespace separate
  the cells of a table without a delimiter, whose cells are never quoted;
- a line whose first character that is not a space is ``#`` is a comment; a ``#`` inside a row is part
  of its cell (``run #2``), not the start of a comment;
- a row that is the header again (files joined one after another, ``cat a.csv b.csv``) is passed over
  and its line kept in :attr:`RowParser.repeated_headers`, for the reader to note.

A used cell that is no number is an :class:`InputFormatError` naming the file, line and column, as is one a
reader's converter refuses (:class:`BadCell` says why). ``nan``/``NaN`` is a number (a NaN sample); a cell
of digits that are not ASCII (``١٢``, fullwidth ``１２``) or with an underscore (``1_0``) is not, though
Python's ``float`` reads it (:func:`number`): NumPy, JSON and spreadsheets do not.

Speed: a chunk goes to ``numpy.loadtxt`` whole. Its rows' cells are counted first (one ``str.count`` a
line); a line holding a quote is split as CSV and handed on unquoted, its unused cells blanked, so that
NumPy never judges a quote. Only a chunk NumPy refuses is walked a cell at a time, to name its first bad
cell (or, when every cell is a number after all, to parse it that way).
"""

from __future__ import annotations

import csv
import io
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import repeat
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol.errors import InputFormatError

Array = NDArray[np.float64]
_UNUSED = "-"
"""What an unused cell of a re-written (quoted) line becomes: never parsed; not empty, so that a table
split at runs of whitespace keeps its cell count."""


class BadCell(ValueError):
    """Raised by a reader's converter for a cell it refuses; its message is what the error says."""


def number(text: str) -> float:
    """A cell's text as a number, as NumPy, JSON and a spreadsheet read one: ``ValueError`` for what only
    Python's ``float`` takes — digits that are not ASCII (``"١٢"``, fullwidth ``"１２"``), ``"1_0"``."""
    if not text.isascii() or "_" in text:
        raise ValueError(text)
    return float(text)


def shown(cell: str, keep: int = 40) -> str:
    """A cell for a message: its repr, cut to ``keep`` characters (a bad cell can be a megabyte)."""
    return repr(cell) if len(cell) <= keep else repr(cell[:keep]) + f"… ({len(cell)} characters)"


def cells_of(line: str, delimiter: str | None) -> list[str]:
    """A line's cells as written (quotes kept on a cell without a delimiter in it: :func:`cell_text`
    removes them). ``delimiter`` None: runs of whitespace. Raises ``csv.Error`` on a line the CSV
    reader refuses."""
    if delimiter is None:
        return line.split()
    line = line.rstrip("\r")
    if '"' not in line:
        return line.split(delimiter)
    return next(csv.reader([line], delimiter=delimiter, skipinitialspace=True), [""])


def cell_text(cell: str) -> str:
    """A cell's text: spaces and quotes around it removed (``' "2.0" '`` → ``2.0``)."""
    return cell.strip().strip('"')


def is_content(line: str) -> bool:
    """Whether a line is a row: neither blank (white space only) nor a comment (``#`` after spaces). Only
    spaces go before a comment's ``#``: a tab is a delimiter, and a tab-separated row whose first cell is
    empty and whose second begins with ``#`` is a row (it was read as a comment, and half an export's
    samples went with it)."""
    return bool(line.strip()) and not line.lstrip(" ").startswith("#")


@dataclass
class RowParser:
    """Parses chunks of numbered lines of one table into float arrays of its ``used`` columns (and exact
    int64 ones), keeping only those (see the module docstring).

    ``columns`` are the header's names (``col0``… without one); ``used`` the positions read, in the order
    the table gives them; ``converters`` parse a used position's cells (a text code, an empty cell that
    means NaN); ``exact`` (name, position) pairs are also read as int64."""

    columns: tuple[str, ...]
    used: tuple[int, ...]
    source: str
    delimiter: str | None
    decimal_comma: bool
    converters: Mapping[int, Callable[[str], float]] = field(default_factory=dict)
    exact: tuple[tuple[str, int], ...] = ()
    header: bool = False
    repeated_headers: list[int] = field(default_factory=list)
    """The lines that repeat the header (files joined one after another: ``cat a.csv b.csv``), passed
    over; ``header`` says whether the table has one to repeat."""
    header_as_written: tuple[tuple[str, ...], ...] = ()
    """The header's lines as written, when its names are not (a row of units under it folded into them,
    :func:`hil.logs.table.units_under`): the header line's cells and the units row's, each passed over
    as a repeated header when a file joined after the first repeats it."""
    chunks: list[Array] = field(default_factory=list)
    exact_chunks: dict[str, list[NDArray[np.int64]]] = field(default_factory=dict)

    def parse(self, lines: list[str], first_line: int) -> int:
        """Parse ``lines`` (without their line breaks), the first of which is line ``first_line``; returns
        the number of rows kept."""
        return self._parse(lines, first_line)

    def label(self, position: int) -> str:
        """A column for messages: its header name, or its 1-based position when it has none."""
        return self.columns[position] or f"{position + 1}, no name in the header"

    def _parse(self, lines: list[str], first_line: int) -> int:
        prepared = self._prepared(lines)
        if prepared is None:  # a row of the wrong width, or a quoted used cell NumPy would misread
            return self._walk(lines, first_line)
        text, rows = prepared
        if rows == 0:
            return 0
        every = rows is None  # every column used, every line without a quote: NumPy checks the widths
        data = self._loadtxt(text, float, None if every else self.used)
        if data is None or data.shape[1] != (len(self.columns) if every else len(self.used)):
            return self._walk(lines, first_line)
        if rows is not None and data.shape[0] != rows:
            return self._walk(lines, first_line)
        if every and self.used != tuple(range(len(self.columns))):
            data = data[:, self.used]
        self.chunks.append(data)
        for name, position in self.exact:
            ints = self._loadtxt(text, np.int64, (position,))
            if ints is None or len(ints) != len(data):  # a cell that is no integer: each cell on its own
                ints = self._exact_cells(text, position, data[:, self.used.index(position)])
            self.exact_chunks.setdefault(name, []).append(ints.reshape(-1))
        return int(data.shape[0])

    def _exact_cells(self, text: str, position: int, floats: Array) -> NDArray[np.int64]:
        """The cells of an exact column, each as :func:`_exact_int` reads it: an integer exactly, any other
        (a ``nan``, a re-save's ``1.679e18``) at its float's precision — so that one row's ``nan`` leaves
        every other row of its chunk exact."""
        cells = self._loadtxt(text, str, (position,))
        if cells is None or len(cells) != len(floats):  # never seen: loadtxt read the chunk's floats
            fits = np.isfinite(floats) & (np.abs(floats) < 2.0**63)
            return np.where(fits, floats, 0.0).astype(np.int64)
        return np.array([_exact_int(c, f) for c, f in zip(cells.reshape(-1), floats, strict=True)], np.int64)

    def _prepared(self, lines: list[str]) -> tuple[str, int | None] | None:
        """The chunk as NumPy is given it — blank and comment lines emptied, a line holding a quote
        re-written unquoted (:meth:`_unquoted`) — and its number of rows (None: left to NumPy, which reads
        every column and so checks every row's width); None when a row has the wrong number of cells or
        cannot be re-written (walked instead, to name it)."""
        width = len(self.columns)
        text = "\n".join(lines)
        if '"' not in text and "#" not in text:
            if len(self.used) == width:
                return self._decimal_point(text), None
            if (width > 1 or self.delimiter is None) and self._widths(lines) == {width}:
                return self._decimal_point(text), len(lines)  # rows only (a blank line is narrower)
        out: list[str] = []
        rows = 0
        for line in lines:
            if not is_content(line):
                out.append("")
                continue
            rows += 1
            if '"' in line:
                unquoted = self._unquoted(line)
                if unquoted is None:
                    return None
                line = unquoted
            elif self._widths([line]) != {width}:
                return None
            out.append(line)
        return self._decimal_point("\n".join(out)), rows

    def _widths(self, lines: list[str]) -> set[int]:
        """The numbers of cells of lines without quotes (a blank line has 0 at runs of whitespace, 1 at a
        delimiter)."""
        if self.delimiter is None:
            return set(map(len, map(str.split, lines)))
        return {count + 1 for count in set(map(str.count, lines, repeat(self.delimiter)))}

    def _decimal_point(self, text: str) -> str:
        return text.replace(",", ".") if self.decimal_comma else text

    def _unquoted(self, line: str) -> str | None:
        """A line holding a quote, split as CSV and joined again without quotes, its unused cells blanked
        (their text may hold the delimiter): None when it has the wrong number of cells or a used cell
        would change the cells NumPy sees — one holding the delimiter, a quote or nothing at all between
        runs of whitespace — (no number: walked, to name it)."""
        try:
            cells = cells_of(line, self.delimiter)
        except csv.Error:
            return None
        if len(cells) != len(self.columns):
            return None
        out = [_UNUSED] * len(cells)
        for position in self.used:
            text = cell_text(cells[position])
            if (self.delimiter or " ") in text or '"' in text or "\r" in text:
                return None
            if not text and self.delimiter is None:  # ``""`` between spaces: joined, it would vanish
                return None
            out[position] = text
        return (self.delimiter or " ").join(out)

    def _loadtxt(self, text: str, dtype: type, usecols: Sequence[int] | None) -> NDArray[Any] | None:
        """``numpy.loadtxt`` of the columns ``usecols`` (None: all) — None when it refuses a cell; no other
        column is parsed."""
        converters: dict[int, Callable[[str], float]] | None = None
        if dtype is float:
            converters = {p: f for p, f in self.converters.items() if usecols is None or p in usecols}
            converters = converters or None
        try:
            with warnings.catch_warnings():  # a piece of blank lines only is no data, and no news
                warnings.simplefilter("ignore", UserWarning)
                return np.loadtxt(  # type: ignore[no-any-return, call-overload]
                    io.StringIO(text),
                    delimiter=self.delimiter,
                    ndmin=2,
                    dtype=dtype,
                    comments=None,
                    quotechar=None,
                    usecols=usecols,
                    converters=converters,
                )
        except (ValueError, KeyError, OverflowError):
            return None

    def _walk(self, lines: Sequence[str], first_line: int) -> int:
        """The chunk a cell at a time: an InputFormatError at the first row of the wrong width or the
        first bad used cell (in file order); when there is none (a cell Python reads as a number and NumPy
        does not), the rows as read. Returns the number of rows kept."""
        order = sorted(self.used)
        rows: list[list[float]] = []
        exact: dict[str, list[int]] = {name: [] for name, _ in self.exact}
        for i, line in enumerate(lines):
            if not is_content(line):
                continue
            line_no = first_line + i
            try:
                cells = cells_of(line, self.delimiter)
            except csv.Error as exc:
                raise InputFormatError(f"not a CSV row ({exc})", self.source, line_no) from None
            if self.header and len(cells) == len(self.columns) and self._is_header(cells):
                self.repeated_headers.append(line_no)
                continue
            if len(cells) != len(self.columns):
                what = f"{len(cells)} values, expected {len(self.columns)}"
                if self.delimiter is not None and len(self.columns) > 1 and not self.columns[-1]:
                    what += " (the header ends in a delimiter)"
                raise InputFormatError(what, self.source, line_no)
            texts = {p: cell_text(cells[p]) for p in order}
            values = {p: self._value(texts[p], p, line_no) for p in order}
            rows.append([values[p] for p in self.used])
            for name, position in self.exact:
                exact[name].append(_exact_int(texts[position], values[position]))
        if rows:
            self.chunks.append(np.array(rows, dtype=float).reshape(len(rows), len(self.used)))
            for name, values_of in exact.items():
                self.exact_chunks.setdefault(name, []).append(np.array(values_of, dtype=np.int64))
        return len(rows)

    def _is_header(self, cells: Sequence[str]) -> bool:
        """Whether a row's cells are the header's names (stripped and unquoted, as the header's are)."""
        texts = tuple(cell_text(c).strip() for c in cells)
        return texts == tuple(self.columns) or texts in self.header_as_written

    def _value(self, text: str, position: int, line_no: int) -> float:
        """A used cell's value; an InputFormatError naming it when it is none."""
        convert = self.converters.get(position)
        try:
            if convert is not None:
                return float(convert(text))
            return number(text.replace(",", ".") if self.decimal_comma else text)
        except (ValueError, KeyError) as exc:
            if isinstance(exc, BadCell):
                what = str(exc)
            else:
                what = f"{shown(text)} is not a number" if text else "empty value"
            raise InputFormatError(what, self.source, line_no, self.label(position)) from None

    def arrays(self) -> tuple[Array, dict[str, NDArray[np.int64]]]:
        """The rows kept, (N, len(used)) floats, and the exact columns, N int64 each."""
        data = np.concatenate(self.chunks) if self.chunks else np.zeros((0, len(self.used)))
        self.chunks.clear()
        exact = {}
        for name, _ in self.exact:
            parts = self.exact_chunks.get(name)
            exact[name] = np.concatenate(parts) if parts else np.zeros(0, np.int64)
        return data, exact


def _exact_int(cell: str, value: float) -> int:
    """A cell as int64: exactly when it is an integer, else its float's (0 when that is none: the float
    column marks the row unusable)."""
    try:
        whole = int(cell)
    except ValueError:
        whole = None
    if whole is not None and -(2**63) <= whole < 2**63:
        return whole
    return int(value) if np.isfinite(value) and abs(value) < 2.0**63 else 0
