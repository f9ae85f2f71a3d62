"""Numeric text tables (CSV and friends) read as a stream, with errors that say file, line and column.

A table is read in pieces of about :data:`~hil.files.bounded.CHUNK_BYTES` of lines
(:func:`hil.files.bounded.read_lines`): each piece is parsed by :class:`~hil.logs.rows.RowParser`
(``numpy.loadtxt``) and only the floats of the columns its reader uses are kept, so memory is bounded by
the samples kept (not by the file's size), and a bad line fails as soon as its piece is parsed — the rest
of the file is never read. Only the used columns must hold numbers; the cells of every other column are
never parsed, and may hold text or nothing (:mod:`hil.logs.rows`, which also says what every row must
be). When a piece fails, its lines are walked to raise :class:`InputFormatError` naming the first bad
cell. A line of spaces is a blank line. ``nan``/``NaN`` cells are numbers (NaN samples, counted and
dropped later by the merge); anything else unparseable in a used column is an error. Files are read as
UTF-8 whatever their encoding (:mod:`hil.logs.encoding`, :func:`text_lines`); a log's archives are opened
by :mod:`hil.logs.archive`.

What a log may be is bounded by what its files are (:mod:`hil.files.bounded`): a member yields at most
:data:`~hil.files.bounded.MAX_MEMBER_BYTES` decompressed and at most
:data:`~hil.files.bounded.MAX_COMPRESSION_RATIO` times its compressed size, a line is at most
:data:`~hil.files.bounded.MAX_LINE_BYTES`, a log holds at most :data:`~hil.files.bounded.MAX_MEMBERS` files
and :data:`MAX_LOG_SAMPLES` rows; past any of them the reader stops with an error naming the file and line.
"""

from __future__ import annotations

import codecs
import csv
import gzip
import io
import logging
import re
import zipfile
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

from hil.files.bounded import (
    CHUNK_BYTES,
    FOLDER,
    MAX_DOCUMENT_BYTES,
    MAX_LINE_BYTES,
    MAX_MEMBER_BYTES,
    MAX_MEMBERS,
    PIPE,
    LimitedReader,
    Unterminated,
    input_kind,
    read_lines,
)
from hil.logs.archive import (
    Member,
    archive_suffix,
    file_member,
    kind_of,
    members_of,
    os_litter,
    piped_name,
    spooled_pipe,
    without_suffix,
)
from hil.logs.encoding import decode_legacy, decode_text, utf8_stream
from hil.logs.rows import RowParser, cell_text, cells_of, is_content
from protocol.errors import InputFormatError

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]
HEAD_BYTES = 4096
MAX_LOG_SAMPLES = 2_000_000
"""The most rows a log's tables may hold together (2 million: 1.5 hours of three sensors at 100 Hz). The
parsed floats of a log cost about 100 bytes a row while read; a longer log is refused naming the file and
the line it reached, rather than read into all the memory there is."""
_TEXT_BREAK = re.compile(r"\r\n|\r|\n")
"""The line breaks of a table's text, as :func:`hil.files.bounded.read_lines` splits its bytes."""
MAX_RAW_BYTES = 64 << 20
"""The most a member read whole (a MATLAB ``.mat`` file) may hold: the BROAD and Qualisys files are 4 MB."""


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
    repeated_headers: tuple[int, ...] = ()
    """The lines that repeat the header, passed over (files joined one after another)."""
    cut_short: InputFormatError | None = None
    """Why the file's last line, which had no line break, could not be read (dropped): a recording stopped
    in the middle of a write; None when there was none or it was read."""
    units_line: int = 0
    """The line of a row of units under the header (``ns,s,rad/s,rad/s,rad/s``: :func:`units_under`), read
    as the header's units; 0 when there was none."""

    def layout_notes(self) -> list[str]:
        """What a reader notes of how the table was laid out: the lines that repeated its header, a last
        line cut short."""
        notes = []
        lines = self.repeated_headers
        if lines:
            shown_lines = ", ".join(map(str, lines[:5])) + (", …" if len(lines) > 5 else "")
            notes.append(
                f"{self.source}: the header repeated on {len(lines)} line(s) ({shown_lines}): files joined "
                "one after another, read as one (each line passed over)"
            )
        if self.cut_short is not None:
            notes.append(cut_short_note(self.cut_short))
        if self.units_line:
            notes.append(
                f"{self.source}: line {self.units_line} under the header holds the columns' units: read as "
                f"the header's ({', '.join(c for c in self.columns if _HAS_UNIT.search(c))})"
            )
        return notes

    def column(self, name: str) -> Array:
        try:
            return self.data[:, self.columns.index(name)]
        except ValueError:
            raise InputFormatError(
                f"no column {name!r} (columns: {', '.join(self.columns)})",
                self.source,
                self.header_line or None,
            ) from None


_PACKED_MAGIC = ((b"\x1f\x8b", ".gz"), (b"PK\x03\x04", ".zip"), (b"BZh", ".bz2"), (b"\xfd7zXZ\x00", ".xz"))
"""The first bytes of compressed or archive data, and the suffix saying so (:meth:`Container.packed_as`)."""


class Container:
    """Files of a log: a directory, an archive (zip or tar, :mod:`hil.logs.archive`), or a single file;
    a context manager, whose :meth:`close` frees the archives and temporary files it holds at once (not
    when it is garbage-collected).
    ``names()`` lists member file names (paths relative to the container, '/'-separated); ``lines(name)``
    streams one's lines (``.gz`` members decompressed, UTF-16 transcoded: :mod:`hil.logs.encoding`; see
    the module docstring for the bounds), ``head(name)`` gives its first lines, ``where(name)`` says
    where it is. ``samples`` counts the rows read from its tables (:meth:`count_samples`); ``name`` is
    the log's own name (its folder's or archive's, without the archive's suffix; the folder an archive's
    files all lie in when they do)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        kind = input_kind(self.path, InputFormatError)  # a device or a socket refused: never opened
        self._members: dict[str, Member] = {}
        self._held: list[object] = []  # open archives and spooled files, kept while the log is read
        self.samples = 0
        self.name = without_suffix(self.path.name)
        try:
            self._open_members(kind)
        except BaseException:
            self.close()  # what was opened before the error (a spooled tar, an archive inside it)
            raise

    def close(self) -> None:
        """Close what the container holds open — the archives, the temporary files an archive inside
        another and a tar or a pipe were spooled to (deleted as they close) — newest first. Idempotent;
        its members cannot be read after it."""
        held, self._held = self._held, []
        self._members = {}
        for thing in reversed(held):
            close = getattr(thing, "close", None)
            if close is not None:
                try:
                    close()
                except OSError:
                    pass  # a file that cannot be closed is gone: nothing more to free

    def __enter__(self) -> Container:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _open_members(self, kind: str) -> None:
        if kind == FOLDER:
            for p in sorted(self._files()):
                rel = p.relative_to(self.path).as_posix()
                if os_litter(rel):
                    continue
                found = self._archive(p) if archive_suffix(rel) else None
                if found is None:
                    self._add(rel, file_member(p))
                for name, member in found or ():  # an export's archive inside a folder
                    self._add(without_suffix(rel) + "/" + name, member)
        else:
            name = self.path.name
            if kind == PIPE:
                spool, member = spooled_pipe(self.path, self._held)
                found, name = self._archive_in(spool, self.path), piped_name(self.path, spool)
            else:
                found, member = self._archive(self.path), file_member(self.path)
            if found is None:
                self._members[name] = member
            for name, inner in found or ():
                self._add(name, inner)

    def _archive(self, path: Path) -> list[tuple[str, Member]] | None:
        """The members of the archive at ``path`` (:meth:`_archive_in`; None when it is none)."""
        try:
            f = open(path, "rb")  # noqa: SIM115 — held (``_held``) while the log is read
        except OSError as exc:
            raise InputFormatError(f"cannot read ({exc.strerror})", str(path)) from None
        self._held.append(f)
        found = self._archive_in(f, path)
        if found is None:
            self._held.remove(f)
            f.close()
        return found

    def _archive_in(self, f: IO[bytes], path: Path) -> list[tuple[str, Member]] | None:
        """The members of the archive ``f`` (seekable, in ``_held``) read from ``path``, its shared folder
        noted as the log's name when ``path`` is the log; None when it is no archive."""
        kind = kind_of(f)
        if kind is None:
            return None
        shared, members = members_of(f, str(path), kind, self._held)
        if shared and path == self.path:
            self.name = shared.rstrip("/").rsplit("/", 1)[-1]
        return members

    def _files(self) -> Iterator[Path]:
        """The files under the folder, at most :data:`MAX_MEMBERS` of them (an error past that)."""
        seen = 0
        for p in self.path.rglob("*"):
            if p.is_file():
                seen += 1
                if seen > MAX_MEMBERS:
                    raise InputFormatError(f"more than {MAX_MEMBERS} files: not a phone log", str(self.path))
                yield p

    def _add(self, name: str, member: Member) -> None:
        if len(self._members) >= MAX_MEMBERS:
            raise InputFormatError(f"more than {MAX_MEMBERS} files: not a phone log", str(self.path))
        self._members[name] = member

    def names(self) -> list[str]:
        return list(self._members)

    def has(self, name: str) -> bool:
        return name in self._members

    def where(self, name: str) -> str:
        member = self._members.get(name)
        return member.where if member is not None else str(self.path / name)

    def _open(self, name: str, limit: int = MAX_MEMBER_BYTES) -> io.BufferedReader:
        """The member's bytes (a ``.gz`` decompressed), at most ``limit`` of them and at most
        :data:`~hil.files.bounded.MAX_COMPRESSION_RATIO` times what they were compressed from."""
        if name not in self._members:
            raise InputFormatError(f"missing {name}", str(self.path))
        member = self._members[name]
        try:
            raw = member.open()
        except (OSError, zipfile.BadZipFile, NotImplementedError, RuntimeError) as exc:
            raise InputFormatError(f"cannot read ({exc})", member.where) from None
        packed = member.packed
        if name.lower().endswith(".gz"):
            packed = packed if packed is not None else member.stored
            raw = gzip.GzipFile(fileobj=raw)  # type: ignore[assignment]
        return io.BufferedReader(LimitedReader(raw, member.where, limit, packed), 1 << 16)

    def _open_text(self, name: str, limit: int = MAX_MEMBER_BYTES) -> IO[bytes]:
        """The member's bytes as UTF-8 (:func:`hil.logs.encoding.utf8_stream`: UTF-16 transcoded)."""
        f = self._open(name, limit)
        where = self.where(name)
        try:
            return utf8_stream(f, where)
        except _DAMAGED as exc:  # its first bytes, read to look for a byte-order mark
            f.close()
            raise InputFormatError(f"damaged ({exc})", where) from None

    def raw(self, name: str, limit: int = MAX_RAW_BYTES) -> bytes:
        """The member whole: at most ``limit`` bytes (an error naming it past that)."""
        with self._open(name, limit) as f:
            return _guarded(f.read, self.where(name))

    def lines(self, name: str) -> Iterator[list[bytes | None]]:
        """The member's lines, a batch at a time (:func:`hil.files.bounded.read_lines`: ``None`` for a
        line longer than :data:`~hil.files.bounded.MAX_LINE_BYTES`)."""
        with self._open_text(name) as f:
            yield from _guarded_iter(read_lines(f), self.where(name))

    def chunks(self, name: str, limit: int = MAX_MEMBER_BYTES) -> Iterator[bytes]:
        """The member's bytes (a ``.gz`` decompressed), a piece of at most
        :data:`~hil.files.bounded.CHUNK_BYTES` at a time, at most ``limit`` in all (an error naming it
        past that, or past :data:`~hil.files.bounded.MAX_COMPRESSION_RATIO`): for a reader that is not
        line by line (a JSON document of one line). A damaged member is an InputFormatError naming it."""
        where = self.where(name)
        with self._open_text(name, limit) as f:
            while piece := _guarded(lambda: f.read(CHUNK_BYTES), where):
                yield piece

    def packed_as(self, name: str) -> str | None:
        """What compressed or archive data a member is that the readers do not open as it is named, by its
        first bytes: ``".gz"``, ``".zip"``, ``".bz2"``, ``".xz"`` — under a name that does not say so (a
        gzip file named ``Gyroscope.csv``), or a ``.bz2``/``.xz`` under its own name (only a ``.gz`` is read
        decompressed); None for any other (a ``.gz`` or ``.zip`` so named, or unreadable)."""
        if name.lower().endswith((".gz", ".zip")):
            return None
        try:
            with self._open(name) as f:
                first = _guarded(lambda: f.read(6), self.where(name))
        except InputFormatError:
            return None
        return next((ext for magic, ext in _PACKED_MAGIC if first.startswith(magic)), None)

    def head(self, name: str, lines: int = 3) -> list[str]:
        """The first ``lines`` lines (of at most :data:`HEAD_BYTES` bytes), decoded leniently (UTF-8, UTF-16
        transcoded, or a legacy 8-bit text: :func:`hil.logs.encoding.decode_text`): enough to recognise a
        format without reading the file."""
        with self._open_text(name) as f:
            data = _guarded(lambda: f.read(HEAD_BYTES), self.where(name))
        # split at the breaks the rows are read at (\n, \r\n, \r: hil.files.bounded.read_lines), never at
        # the others str.splitlines knows (\x1c-\x1e, \x85, \u2028): a cell may hold those
        pieces = _TEXT_BREAK.split(decode_text(data, final=False))
        if pieces and not pieces[-1]:
            pieces.pop()  # the break that ends the text starts no line
        return pieces[:lines]

    def text(self, name: str) -> str:
        """A small member whole (metadata files, at most
        :data:`~hil.files.bounded.MAX_DOCUMENT_BYTES`): UTF-8, UTF-16 or a legacy 8-bit text
        (:mod:`hil.logs.encoding`)."""
        where = self.where(name)
        with self._open_text(name, MAX_DOCUMENT_BYTES) as f:
            data = _guarded(f.read, where)
        return decode_text(data)

    def same_bytes(self, a: str, b: str) -> bool:
        """Whether members ``a`` and ``b`` hold the same bytes, each decompressed if it is a ``.gz``
        (compared a piece at a time: neither is held whole)."""
        with self._open(a) as fa, self._open(b) as fb:
            while True:
                x = _guarded(lambda: fa.read(CHUNK_BYTES), self.where(a))
                y = _guarded(lambda: fb.read(CHUNK_BYTES), self.where(b))
                if x != y:
                    return False
                if not x:
                    return True

    def count_samples(self, rows: int, where: str, line: int | None) -> None:
        """Count ``rows`` more rows read from the log's tables; past :data:`MAX_LOG_SAMPLES` an
        InputFormatError naming the file and the line reached."""
        self.samples += rows
        if self.samples > MAX_LOG_SAMPLES:
            raise InputFormatError(
                f"the log holds more than {MAX_LOG_SAMPLES} samples: longer than hil reads at once "
                "(cut it into parts)",
                where,
                line,
            )


def one_copy(c: Container, copies: Sequence[str]) -> tuple[str, str | None]:
    """The member to read of ``copies`` — the names one file may have in a log, preferred first (the
    app's ``Gyroscope.csv`` and a ``Gyroscope.csv.gz`` beside it; a tyrex trial's ``….txt.gz`` and the
    ``….txt`` gunzipped beside it) — at least one of which is present, and a note when several are. Copies
    with the same bytes (decompressed: ``gunzip -k``) are read once, noted; different ones are an
    :class:`InputFormatError` naming both: which one is the recording cannot be told, and reading one
    passed the other over without a word."""
    present = [name for name in copies if c.has(name)]
    first = present[0]
    for other in present[1:]:
        if not c.same_bytes(first, other):
            raise InputFormatError(
                f"another copy of {c.where(first)} whose bytes differ (decompressed): which of the two is "
                "the recording cannot be told; remove one",
                c.where(other),
            )
    if len(present) == 1:
        return first, None
    return first, f"{', '.join(present[1:])}: the same bytes as {first} (decompressed), read once"


_DAMAGED = (OSError, EOFError, zipfile.BadZipFile, gzip.BadGzipFile, zlib.error)
"""What reading a damaged member raises: a bad CRC, a truncated stream, and — from inside ``gzip`` and
``zipfile`` — ``zlib.error`` for a deflate stream whose bytes are corrupt (a bit flipped in a ``.gz``)."""


def _guarded(read: Callable[[], bytes], where: str) -> bytes:
    """``read()``, a damaged member (:data:`_DAMAGED`) an InputFormatError."""
    try:
        return read()
    except _DAMAGED as exc:
        raise InputFormatError(f"damaged ({exc})", where) from None


def _guarded_iter(batches: Iterator[list[bytes | None]], where: str) -> Iterator[list[bytes | None]]:
    while True:
        try:
            batch = next(batches)
        except StopIteration:
            return
        except _DAMAGED as exc:
            raise InputFormatError(f"damaged ({exc})", where) from None
        yield batch


def content_head(container: Container, name: str, lines: int = 3, units_row: bool = False) -> list[str]:
    """The first ``lines`` lines of a member that are neither blank nor comments (``# exported by …`` before
    a header), read from its first :data:`HEAD_BYTES`: its header and first rows, to tell its format and
    dialect as :func:`read_table` will read it. ``units_row`` as :func:`read_table`'s: a row of units under
    the header (:func:`units_under`) is folded into the header line (``z`` over ``rad/s``: ``z (rad/s)``),
    so that the first line after it is the first row, as the reader will read them."""
    content = [line for line in container.head(name, 64) if is_content(line)]
    if units_row and len(content) > 1:
        delimiter = sniff_dialect(content[:2])[0]
        folded = _units_of_line(split_header(content[0], delimiter), content[1], delimiter)
        if folded is not None:
            out = io.StringIO()
            csv.writer(out, delimiter=delimiter, lineterminator="").writerow(folded)
            content = [out.getvalue(), *content[2:]]
    return content[:lines]


def _units_of_line(header: Sequence[str], line: str, delimiter: str) -> list[str] | None:
    """:func:`units_under` of a line as text (None when it is no CSV row: the reader names it)."""
    try:
        return units_under(header, cells_of(line, delimiter))
    except csv.Error:
        return None


_UNIT_CELL = re.compile(r"^[(\[]?\s*([^\d\s.+\-(\[)\]][^()\[\]]{0,15}?)\s*[)\]]?$")
"""A cell of a row of units: a unit (``ns``, ``rad/s``, ``m/s^2``, ``µT``, ``°/s``), bare or in
parentheses or brackets, of at most 16 characters, starting with no digit, sign or point."""
_HAS_UNIT = re.compile(r"[(\[][^()\[\]]*[)\]]\s*$")
"""A header name that already ends in a unit in parentheses or brackets (``Time (s)``)."""


def units_under(header: Sequence[str], cells: Sequence[str]) -> list[str] | None:
    """The header's names with their units, when the row ``cells`` right under it is a row of units (a
    tool's or a spreadsheet's re-save: ``time,seconds_elapsed,z,y,x`` over ``ns,s,rad/s,rad/s,rad/s``);
    None when it is a row like any other. A row of units has the header's width, is not the header again,
    holds no number, and holds a unit (:data:`_UNIT_CELL`) in at least half its cells and nothing else in
    the others. Each name is given its unit as the readers read one (``z (rad/s)``: converted to SI by
    :mod:`hil.logs.columns`; ``time (ns)``); a name that already ends in a unit keeps its own. Such a row
    was read as the first row: "'ns' is not a number", the export refused."""
    texts = [c.strip().strip('"').strip() for c in cells]
    if len(texts) != len(header) or len(header) < 2 or texts == list(header):
        return None
    given = [t for t in texts if t]
    if len(given) < max(1, len(header) // 2):
        return None
    for text in given:
        if _UNIT_CELL.match(text) is None or text.lower() in ("nan", "inf", "infinity", "null", "none"):
            return None
        if not any(ch.isalpha() or ch in "°%" for ch in text):
            return None
    return [
        name if not unit or _HAS_UNIT.search(name) else f"{name} ({unit.strip('()[] ')})"
        for name, unit in zip(header, texts, strict=True)
    ]


DELIMITERS = (",", ";", "\t")
"""The separators a CSV may use, in the order a tie between them is decided (:func:`sniff_dialect`): the
apps' comma first."""


def sniff_dialect(head: Sequence[str]) -> tuple[str, bool]:
    """(delimiter, decimal comma) of a CSV from its first non-blank lines ``head`` (header first; comment
    lines passed over). The separator is the one of :data:`DELIMITERS` that splits the header — as CSV
    cells, a quoted name may hold any of them — into the most cells, more than one, and the first data
    line into as many (a tie: the first of :data:`DELIMITERS`): a header name holding a ``;`` or a tab
    (``note; free text``, quoted or not) splits the header but not its rows, and never makes a
    comma-separated file read as one with semicolons. When no separator agrees so (a first row of the
    wrong width, which the reader then names), the one that splits the header into the most cells; a
    header of one cell: a comma. With a separator other than the comma, a comma in the first data line is
    a decimal comma (a spreadsheet's export in a European locale, phyphox's "semicolon, decimal comma")."""
    lines = [line for line in head if is_content(line)]
    header = lines[0] if lines else ""
    first = lines[1] if len(lines) > 1 else ""
    widths = {d: _width(header, d) for d in DELIMITERS}
    agreeing = [d for d in DELIMITERS if widths[d] > 1 and (not first or _width(first, d) == widths[d])]
    delimiter = max(agreeing or DELIMITERS, key=lambda d: widths[d])  # a tie: the first of DELIMITERS
    return delimiter, delimiter != "," and "," in first


def _width(line: str, delimiter: str) -> int:
    """How many CSV cells ``line`` splits into at ``delimiter`` (0 when it is no CSV row)."""
    try:
        return len(next(csv.reader([line], delimiter=delimiter, skipinitialspace=True), []))
    except csv.Error:
        return 0


def split_header(line: str, delimiter: str | None) -> list[str]:
    """Header cells, quotes removed (``"Time (s)","Acceleration x (m/s^2)"``)."""
    if delimiter is None:
        return [c.strip('"') for c in line.split()]
    return [c.strip().strip('"').strip() for c in next(csv.reader([line], delimiter=delimiter))]


@dataclass(frozen=True)
class Header:
    """A table's header as a reader's ``use`` sees it: its ``columns`` (names, stripped and unquoted;
    ``col0``… without a header), the file (``source``, for messages) and its 1-based ``line`` (0 without
    a header)."""

    columns: tuple[str, ...]
    source: str
    line: int


Use = Callable[[Header], Sequence[str]]
"""A reader's choice of the columns it reads, by name, from the table's header (raising
InputFormatError naming the header when a column it needs is missing)."""


def read_table(
    container: Container,
    name: str,
    delimiter: str | None = ",",
    header: bool = True,
    decimal_comma: bool = False,
    min_columns: int = 1,
    use: Use | Sequence[str] | None = None,
    exact_columns: Sequence[str] = (),
    converters: Mapping[str, Callable[[str], float]] | None = None,
    recording: bool = True,
    units_row: bool = False,
) -> Table:
    """Stream one member of ``container`` into a :class:`Table` (see the module docstring) of the columns
    ``use`` names — a list of names, or a function of the :class:`Header` that returns them — in that
    order; None reads them all. The cells of every other column are never parsed: they may hold text, or
    nothing (:mod:`hil.logs.rows`). A name the header holds twice is its first column.

    ``delimiter`` None means runs of whitespace; ``decimal_comma`` for exports such as phyphox's
    "semicolon/tab, decimal comma" CSV. Lines starting with ``#`` are comments; blank lines are skipped.
    Every data row must have as many cells as the header (or the first row): one with more or fewer is
    an InputFormatError naming its line. ``exact_columns`` are also read as int64 (e.g. nanosecond epoch
    times, which float64 rounds to 256 ns); ``converters`` (by column name) parse cells that are no
    numbers (a text code: raising :class:`~hil.logs.rows.BadCell` to say why a cell is refused). The rows
    read count towards the log's :data:`MAX_LOG_SAMPLES`.

    A column whose header name is empty is a column like any other, named by its position in errors: no
    reader names one, so its cells are never parsed. The last one of a header that ends in a delimiter
    (``time,seconds_elapsed,z,y,x,``: a tool that re-saved the file ending every line in a delimiter) is
    that too — its rows end in an empty cell (``…,1.23,``), or hold anything there — and ``use=None``
    leaves it out; a row without that cell is an error naming its line, as any row too short is.

    A last data line without a line break is dropped (:attr:`Table.cut_short`, warned): a recording
    stopped in the middle of a write may have cut it mid-number, and a value cut short ("0.0036" of
    "0.00366519") still parses, wrong. At most one sample is lost, and said. ``recording=False`` reads such
    a line (a file of settings written by hand, e.g. one number: no recording that was cut).

    ``units_row``: a row of units right under the header (:func:`units_under`: a tool's re-save) gives
    the header's names their units (``z (rad/s)``), and is no row (:attr:`Table.units_line`, noted)."""
    source = container.where(name)
    parser: RowParser | None = None
    header_line = 0
    units_line = 0
    cut_short = None
    for first_line, lines in text_lines(container, name):
        start = 0
        if parser is None:
            found = _first_content(lines)
            if found is None:
                continue
            columns, header_line = _columns(lines[found], first_line + found, header, delimiter)
            # a row of units under the header (units_row): its units in the header's names, no row
            under = _first_content(lines[found + 1 :]) if units_row and header and delimiter else None
            units = lines[found + 1 + under] if under is not None else ""
            folded = _units_of_line(columns, units, delimiter) if under is not None and delimiter else None
            written: tuple[tuple[str, ...], ...] = ()
            if folded is not None and delimiter is not None:
                written = (columns, tuple(cell_text(c).strip() for c in cells_of(units, delimiter)))
                columns, units_line = tuple(folded), first_line + found + 1 + (under or 0)
            trailing = header and delimiter is not None and len(columns) > 1 and columns[-1] == ""
            named = len(columns) - trailing  # ``a,b,c,``: a re-save that ends every line in a delimiter
            if named < min_columns:
                raise InputFormatError(
                    f"expected at least {min_columns} columns, found {named}: is this the right file?",
                    source,
                    header_line or first_line + found,
                )
            head = Header(columns, source, header_line or first_line + found)
            parser = _parser(head, use, named, exact_columns, converters or {}, delimiter, decimal_comma)
            parser.header = header
            parser.header_as_written = written
            start = found + 1 if header else found
            if units_line:
                start = units_line - first_line + 1
        last = isinstance(lines, Unterminated) and not start  # a header alone is no cut-short row
        if last and recording and _first_content(lines) is not None:
            # a last data line without a line break: the recording stopped mid-write, maybe mid-number
            # ("…,0.0036651" of "…,0.00366519158706069") — a value that parses is no proof it is whole;
            # dropped always (at most one sample), as one that does not parse is, and said
            cut_short, rows = InputFormatError("no line break after it", source, first_line), 0
            logger.warning("%s", cut_short_note(cut_short))
            container.count_samples(rows, source, first_line)
            continue
        try:
            rows = parser.parse(lines[start:], first_line + start)
        except InputFormatError as exc:
            if not last:
                raise
            cut_short, rows = exc, 0
            logger.warning("%s", cut_short_note(exc))
        container.count_samples(rows, source, first_line + len(lines) - 1)
    if parser is None:
        raise InputFormatError("empty file: no header and no data", source)
    data, exact = parser.arrays()
    used = tuple(parser.columns[p] for p in parser.used)
    return Table(
        used, data, source, header_line, exact, tuple(parser.repeated_headers), cut_short, units_line
    )


def _parser(
    head: Header,
    use: Use | Sequence[str] | None,
    named: int,
    exact_columns: Sequence[str],
    converters: Mapping[str, Callable[[str], float]],
    delimiter: str | None,
    decimal_comma: bool,
) -> RowParser:
    """The row parser of a table with header ``head``: the columns ``use`` names (None: the first
    ``named``, all but a re-save's trailing empty one) and the exact ones, by their positions; a name the
    header lacks is an InputFormatError naming the header."""
    columns = head.columns
    used = list(range(named)) if use is None else []
    names = [] if use is None else list(use(head) if callable(use) else use)
    for column in names + [c for c in exact_columns if c in columns]:
        if column not in columns:
            what = f"no column {column!r} (columns: {', '.join(columns)})"
            raise InputFormatError(what, head.source, head.line or None)
        if columns.index(column) not in used:
            used.append(columns.index(column))
    by_name = {columns[p]: p for p in reversed(used)}  # a name read twice: its first column
    return RowParser(
        columns,
        tuple(used),
        head.source,
        delimiter,
        decimal_comma,
        {by_name[c]: f for c, f in converters.items() if c in by_name},
        tuple((c, by_name[c]) for c in dict.fromkeys(exact_columns) if c in by_name),
    )


def cut_short_note(why: InputFormatError) -> str:
    """What a reader says of a last line dropped because it was cut short (``why`` it could not be read)."""
    return f"{why}: the last line, without a line break, cut short (a recording stopped mid-write): dropped"


def text_lines(container: Container, name: str) -> Iterator[tuple[int, list[str]]]:
    """The member's lines as text, a batch at a time with the 1-based number of its first line (a BOM
    skipped; UTF-16 transcoded, :mod:`hil.logs.encoding`). A file whose first bytes that are not UTF-8
    lie in its header (or in the blank and comment lines before it) is a legacy 8-bit text, read as
    Windows-1252 throughout (``µT``, ``°/s`` saved by an old editor). A line longer than
    :data:`~hil.files.bounded.MAX_LINE_BYTES`, one holding a NUL byte (binary data) or, in a UTF-8 file,
    one that is not UTF-8 is an :class:`InputFormatError` naming its line — after the lines before it have
    been given, so that an earlier bad cell is the one reported."""
    source = container.where(name)
    line_no = 1
    legacy = False
    content = False  # a line with content (the header, or a row) has been given
    for batch in container.lines(name):
        if line_no == 1 and batch[0] is not None and batch[0].startswith(codecs.BOM_UTF8):
            batch[0] = batch[0][len(codecs.BOM_UTF8) :]
        good, problem, not_utf8 = _good_prefix(batch, legacy)
        if not_utf8 and not content and _first_content(good) is None:
            legacy = True  # its header is not UTF-8: the whole file is in a legacy encoding
            good, problem, _ = _good_prefix(batch, legacy)
        if isinstance(batch, Unterminated):  # the last line: cut short, maybe inside a character
            if not_utf8 and problem is not None and batch[0] is not None:
                good, problem = [batch[0].decode("utf-8", "replace")], None
            good = Unterminated(good)
        if good:
            content = content or _first_content(good) is not None
            yield line_no, good
        if problem is not None:
            raise InputFormatError(problem, source, line_no + len(good))
        line_no += len(batch)


def _good_prefix(batch: list[bytes | None], legacy: bool = False) -> tuple[list[str], str | None, bool]:
    """The batch's lines decoded (as UTF-8, or Windows-1252 when ``legacy``) up to its first bad one, what
    is wrong with that one (None: all good), and whether that is bytes that are not UTF-8."""
    end = next((i for i, line in enumerate(batch) if line is None), len(batch))
    problem = None
    if end < len(batch):
        problem = (
            f"a line longer than {MAX_LINE_BYTES} bytes: binary data or no line breaks, not a text table"
        )
    blob = b"\n".join(batch[:end])  # type: ignore[arg-type]  # None only from ``end`` on
    nul = blob.find(b"\x00")
    if nul >= 0:
        end = blob.count(b"\n", 0, nul)
        problem = "binary data (a NUL byte), not a text table"
        blob = b"\n".join(batch[:end])  # type: ignore[arg-type]
    if legacy:
        return (decode_legacy(blob).split("\n") if end else []), problem, False
    try:
        text = blob.decode("utf-8")
    except UnicodeDecodeError as exc:
        end = blob.count(b"\n", 0, exc.start)
        text = b"\n".join(batch[:end]).decode("utf-8")  # type: ignore[arg-type]
        return (_lines_of(text) if end else []), f"not UTF-8 text ({exc.reason})", True
    return (_lines_of(text) if end else []), problem, False


BYTE_ORDER_MARK = "\ufeff"
"""U+FEFF as text. A file's first is skipped as it is read (:func:`text_lines`); one that starts a later
line is the mark of a file joined after the first (``cat a.csv b.csv`` of two exports saved with one, in
UTF-8 or UTF-16): its repeated header was "'\\ufefftime' is not a number", its first row (a file without
a header) a bad cell. It is never part of a cell."""


def _lines_of(text: str) -> list[str]:
    """A decoded batch's lines, each without a byte-order mark at its start (:data:`BYTE_ORDER_MARK`)."""
    lines = text.split("\n")
    if BYTE_ORDER_MARK in text:
        return [line.removeprefix(BYTE_ORDER_MARK) for line in lines]
    return lines


def _first_content(lines: Sequence[str]) -> int | None:
    """The index of the first line that is neither blank nor a comment (None: there is none)."""
    for i, line in enumerate(lines):
        if is_content(line):
            return i
    return None


def _columns(line: str, line_no: int, header: bool, delimiter: str | None) -> tuple[tuple[str, ...], int]:
    """The table's columns from its first line (its header, or ``col0``… for as many cells as the first
    row), and the header's line number (0 without one)."""
    if header:
        return tuple(split_header(line, delimiter)), line_no
    return tuple(f"col{i}" for i in range(len(cells_of(line, delimiter)))), 0
