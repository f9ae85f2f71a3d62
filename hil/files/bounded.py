"""Reading files bounded by what they are, not by what they claim.

Every file the project takes from outside — a phone log and each member of its zip, a run directory's
telemetry, events and summary, a scenario, a dispersion or calibration file — is read through here, so
that no input can make a reader hold more than a fixed amount of memory or parse for ever:

- a stream is read in pieces of :data:`CHUNK_BYTES`, and cut into lines of at most :data:`MAX_LINE_BYTES`
  (:class:`LineSplitter`): a line longer than that is reported as one damaged line (``None``) and skipped
  to its end without being held, whatever the file says;
- a member of a log (a file, a zip member, a ``.gz``) yields at most :data:`MAX_MEMBER_BYTES`
  decompressed, and a compressed one at most :data:`MAX_COMPRESSION_RATIO` times its compressed size
  (:class:`LimitedReader`): a zip bomb is refused after its first megabytes, not after it has filled the
  memory. The count is of the bytes that come out, not of the sizes the archive's header claims;
- a path is read only if it is a regular file, a folder or a pipe (:func:`input_kind`): a device or a
  socket is a typed error naming it before anything opens it (``/dev/zero`` never ends; a serial port or
  a terminal given for a file waits for input for ever);
- a document read whole (TOML, JSON) is at most :data:`MAX_DOCUMENT_BYTES` (:func:`read_document`) and
  nested at most :data:`MAX_NESTING` deep (:func:`load_json`, :func:`load_toml`): deeper nesting is a
  typed error naming the file and the key, never a ``RecursionError`` in a parser or in the code that walks
  the result;
- a number in such a document is one a float holds (:func:`beyond_float`): TOML and JSON read an integer of
  any size (up to Python's 4300 digits) as an exact ``int``, and the first ``float()`` or ``math.isfinite``
  of one beyond ±1.8e308 in a reader's checks was an ``OverflowError`` traceback; such an integer (and one
  too long for Python to read at all) is a typed error naming the file and the key, at the load.

Each limit is an error of the project's one exception tree naming the file (and the line or key), or, for
the readers that keep going past a damaged line (a run directory's telemetry and events), a counted drop.
"""

from __future__ import annotations

import io
import json
import os
import re
import select
import stat
import sys
import tomllib
from collections.abc import Callable, Iterator
from typing import IO, Any, TypeVar

from protocol.errors import ConfigError, HilError, InputFormatError

CHUNK_BYTES = 1 << 18
"""Bytes read from a stream at once: with one partial line (:data:`MAX_LINE_BYTES`), the most a line
reader holds. A piece's lines are held as a batch, ~100 bytes of objects each when they are empty: at 1 MiB
a piece of blank lines took ~100 MB to read (a CI run's hostile-file property, over its 96 MB bound); at
256 KiB, ~28 MB."""
MAX_LINE_BYTES = 1 << 20
"""The longest line a text file may have (1 MiB; a sensor log's lines are under 200 bytes, a run's
telemetry rows a few kB): a longer one is binary data or a file without line breaks."""
MAX_MEMBER_BYTES = 256 << 20
"""The most one member of a log (a file, a zip member, a ``.gz``) may hold, decompressed (256 MiB: about
four million rows of a phone's CSV)."""
MAX_COMPRESSION_RATIO = 100
"""The most a compressed member may expand (decompressed bytes per compressed byte). A phone's CSV
compresses 3-10 times; a zip bomb 1000 times. Checked once :data:`RATIO_GRACE_BYTES` have come out, so a
small member of repeated values is never refused."""
RATIO_GRACE_BYTES = 1 << 20
MAX_DOCUMENT_BYTES = 16 << 20
"""The most a document read whole may hold (16 MiB): a scenario, a dispersion or calibration file, a bench
CSV, a run's ``summary.json``, a campaign's ``campaign.json``. Such files are a few kB."""
MAX_NESTING = 32
"""The deepest a JSON or TOML document may nest (tables, arrays, objects): the project's own files nest 4
deep at most."""
MAX_MEMBERS = 10_000
"""The most files a log (a folder, a zip) may hold: an export has a dozen."""

_BREAK = re.compile(rb"\r\n|\r|\n")

ErrorFactory = Callable[[str, str], HilError]
"""Makes the error to raise from (detail, where): an error class of :mod:`protocol.errors` such as
:class:`ConfigError` or :class:`InputFormatError`."""


class LimitedReader(io.RawIOBase):
    """A binary stream that yields at most ``limit`` bytes, and (when ``compressed_bytes`` is given: the
    stream decompresses a member of that size) at most :data:`MAX_COMPRESSION_RATIO` bytes per compressed
    byte once :data:`RATIO_GRACE_BYTES` have come out; past either it raises :class:`InputFormatError`
    naming ``where``. Counts what comes out, so an archive's claimed sizes do not matter."""

    def __init__(
        self,
        raw: IO[bytes],
        where: str,
        limit: int = MAX_MEMBER_BYTES,
        compressed_bytes: int | None = None,
    ) -> None:
        super().__init__()
        self._raw = raw
        self.where = where
        self.limit = limit
        self.compressed_bytes = compressed_bytes
        self.count = 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        data = self._raw.read(len(view))
        n = len(data)
        view[:n] = data
        self.count += n
        if self.count > self.limit:
            raise InputFormatError(
                f"more than {self.limit} bytes{' decompressed' if self.compressed_bytes else ''}: "
                "larger than any log hil reads",
                self.where,
            )
        packed = self.compressed_bytes
        if packed is not None and self.count > RATIO_GRACE_BYTES:
            if self.count > MAX_COMPRESSION_RATIO * max(packed, 1):
                raise InputFormatError(
                    f"{packed} compressed bytes expand to more than {self.count} "
                    f"(over {MAX_COMPRESSION_RATIO}:1): a compression bomb, not a log",
                    self.where,
                )
        return n

    def close(self) -> None:
        try:
            self._raw.close()
        finally:
            super().close()


class LineSplitter:
    """Bytes in, lines out (sans-IO): :meth:`feed` returns the lines the bytes completed, without their
    line break (``\\n``, ``\\r\\n`` or ``\\r``), in order; a line longer than ``max_line`` bytes comes out
    as ``None`` — its place kept, so line numbers stay right — and its bytes are dropped as they arrive,
    never held. At most ``max_line`` bytes of an unfinished line are held between calls. ``too_long``
    counts the lines given as ``None``."""

    def __init__(self, max_line: int = MAX_LINE_BYTES) -> None:
        self.max_line = max_line
        self.too_long = 0
        self._partial = b""
        self._skipping = False  # inside a line already reported as too long
        self._after_cr = False  # the last byte fed was a \r: a \n next is the same line break

    @property
    def pending(self) -> int:
        """Bytes of the unfinished line held (0 while skipping a long one)."""
        return len(self._partial)

    def feed(self, data: bytes) -> list[bytes | None]:
        if self._after_cr and data.startswith(b"\n"):
            data = data[1:]
        if data:
            self._after_cr = data.endswith(b"\r")
        parts = _BREAK.split(data)
        lines: list[bytes | None] = []
        if len(parts) == 1:
            self._grow(parts[0], lines)
            return lines
        if self._skipping:  # the long line ends here: reported when it grew too long
            self._skipping = False
        else:
            lines.append(self._checked(self._partial + parts[0]))
        self._partial = b""
        for middle in parts[1:-1]:
            lines.append(self._checked(middle))
        self._grow(parts[-1], lines)
        return lines

    def end(self) -> list[bytes | None]:
        """The last line of a file that does not end with a line break (nothing if it does)."""
        partial, self._partial = self._partial, b""
        skipping, self._skipping = self._skipping, False
        return [partial] if partial and not skipping else []

    def _checked(self, line: bytes) -> bytes | None:
        if len(line) <= self.max_line:
            return line
        self.too_long += 1
        return None

    def _grow(self, data: bytes, lines: list[bytes | None]) -> None:
        if self._skipping or not data:
            return
        if len(self._partial) + len(data) > self.max_line:
            self._partial = b""
            self._skipping = True
            self.too_long += 1
            lines.append(None)
        else:
            self._partial += data


_Line = TypeVar("_Line")


class Unterminated(list[_Line]):
    """The last batch of a stream that ended without a line break: its one line, which may be cut short
    (a recording stopped in the middle of a write, a copy made while the file grew). A reader that cannot
    parse it drops it and says so, rather than refusing the whole file for it."""


def read_lines(
    stream: IO[bytes], max_line: int = MAX_LINE_BYTES, chunk: int = CHUNK_BYTES
) -> Iterator[list[bytes | None]]:
    """The lines of ``stream`` (see :class:`LineSplitter`), a batch per piece of ``chunk`` bytes read; a
    last line without a line break comes alone, as an :class:`Unterminated` batch."""
    splitter = LineSplitter(max_line)
    while data := stream.read(chunk):
        lines = splitter.feed(data)
        if lines:
            yield lines
    last = splitter.end()
    if last:
        yield Unterminated(last)


FILE, FOLDER, PIPE = "file", "folder", "pipe"
"""What :func:`input_kind` says a path is."""
_DEVICE_KINDS = (
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def input_kind(path: str | os.PathLike[str], error: ErrorFactory = ConfigError, what: str = "") -> str:
    """What the input at ``path`` (symbolic links followed) is to a reader: :data:`FILE` (a regular file),
    :data:`FOLDER` or :data:`PIPE` (a FIFO: a shell's ``<(…)``, a ``/dev/stdin`` fed by a pipe — read once,
    from its start, as it comes). Anything else is one ``error`` naming it, before it is opened: a device
    (``/dev/zero`` and ``/dev/urandom`` never end; a serial port, such as a board's, or a terminal waits
    for input for ever) or a socket. A path that is not there or cannot be looked at is one too."""
    name = f" ({what})" if what else ""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError as exc:
        raise error(f"no such file{name}", str(path)) from exc
    except OSError as exc:
        raise error(f"cannot read{name}: {exc.strerror or exc}", str(path)) from exc
    if stat.S_ISREG(mode):
        return FILE
    if stat.S_ISDIR(mode):
        return FOLDER
    if stat.S_ISFIFO(mode):
        return PIPE
    kind = next((said for test, said in _DEVICE_KINDS if test(mode)), "not a regular file")
    raise error(f"{kind}, not a file{name}: give the path of a file", str(path))


PIPE_WRITER_WAIT_S = 60.0
"""s: how long an input that is a pipe is waited on for its first bytes (or its writer's end) before it is
refused (:func:`open_input`): a named pipe no program writes to held the command in ``open()`` for ever."""


def open_input(
    path: str | os.PathLike[str],
    error: ErrorFactory = ConfigError,
    what: str = "",
    writer_wait_s: float = PIPE_WRITER_WAIT_S,
) -> IO[bytes]:
    """``path`` opened for reading in binary. A pipe (a named FIFO, a shell's ``<(…)``, ``/dev/stdin`` fed
    by one) is opened without waiting for its writer, then waited on for at most ``writer_wait_s`` for its
    first bytes or its writer's end: one that no program writes to is one ``error`` naming it (``open()``
    of a FIFO without a writer waited for ever: ``hil run --scenario fifo`` hung until killed). Whatever it
    is, an OSError is one ``error`` naming it too."""
    name = f" ({what})" if what else ""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError as exc:
        raise error(f"no such file{name}", str(path)) from exc
    except OSError as exc:
        raise error(f"cannot read{name}: {exc.strerror or exc}", str(path)) from exc
    try:
        if stat.S_ISFIFO(os.fstat(fd).st_mode):
            waiting = select.poll()
            waiting.register(fd, select.POLLIN)
            if not waiting.poll(max(0.0, writer_wait_s) * 1000.0):
                raise error(
                    f"a pipe no program writes to{name} (waited {writer_wait_s:g} s for its first bytes)",
                    str(path),
                )
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def regular_file_if_there(
    path: str | os.PathLike[str], error: ErrorFactory = ConfigError, what: str = "", hint: str = ""
) -> None:
    """Refuse ``path`` if it is there and is not a regular file, naming it: a device or a socket as
    :func:`input_kind` does, a folder or a FIFO (whose open waits for a writer) as ``not a regular file``
    and ``hint``. For the files the project writes and reads back (a run directory's, a campaign's), which
    are always regular files; a missing one is the caller's to say."""
    if os.path.exists(path) and input_kind(path, error, what) != FILE:
        name = f" ({what})" if what else ""
        raise error(f"not a regular file{name}{hint}", str(path))


def read_document(
    path: str | os.PathLike[str],
    error: ErrorFactory = ConfigError,
    what: str = "",
    limit: int | None = MAX_DOCUMENT_BYTES,
) -> str:
    """A text file read whole, as UTF-8 (a BOM skipped): at most ``limit`` bytes (None: no limit, for the
    files a caller bounds otherwise). A missing, unreadable, binary or larger file is one ``error`` naming
    it, never a traceback; only ``limit + 1`` bytes are ever read; a device or a socket is refused before it
    is opened (:func:`input_kind`)."""
    name = f" {what}" if what else ""
    input_kind(path, error, what)  # a device refused before it is opened: a terminal's read blocks
    try:
        with open_input(path, error, what) as f:
            data = f.read() if limit is None else f.read(limit + 1)
    except OSError as exc:
        raise error(f"cannot read{name}: {exc.strerror or exc}", str(path)) from exc
    if limit is not None and len(data) > limit:
        raise error(f"larger than {limit} bytes: not a{name or ' file'} hil wrote or reads", str(path))
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(
            f"not a text file (not UTF-8: {exc.reason} at byte {exc.start}, line {line})", str(path)
        ) from None


def too_deep(value: Any, limit: int = MAX_NESTING) -> str | None:
    """Where ``value`` (parsed JSON or TOML: dicts, lists, scalars) nests deeper than ``limit`` levels —
    the path of the first such element, ``a.b[0]`` — or None. Walked without recursion."""
    stack: list[tuple[Any, int, str]] = [(value, 0, "")]
    while stack:
        node, depth, path = stack.pop()
        if isinstance(node, dict):
            children = [(v, f"{path}.{k}" if path else str(k)) for k, v in node.items() if _nests(v)]
        elif isinstance(node, list):
            children = [(v, f"{path}[{i}]") for i, v in enumerate(node) if _nests(v)]
        else:
            continue
        if depth >= limit:
            return path or "(top level)"
        stack.extend((child, depth + 1, child_path) for child, child_path in children)
    return None


def _nests(value: Any) -> bool:
    return isinstance(value, dict | list)


def beyond_float(value: Any) -> tuple[str, int] | None:
    """The first integer in ``value`` (parsed JSON or TOML: dicts, lists, scalars) that no float holds
    (beyond ±1.8e308, where ``float()`` raises ``OverflowError``), as its key path (``a.b[0]``, ``""`` at
    the top level) and its number of digits; None when every number is one a float holds. Walked without
    recursion. Every reader of a number checks it as a float (``math.isfinite``, a range): an integer
    beyond any float is refused here, once for every file, not in each reader."""
    stack: list[tuple[Any, str]] = [(value, "")]
    while stack:
        node, path = stack.pop()
        if isinstance(node, dict):
            stack.extend((v, f"{path}.{k}" if path else str(k)) for k, v in reversed(node.items()))
        elif isinstance(node, list):
            stack.extend((v, f"{path}[{i}]") for i, v in reversed(list(enumerate(node))))
        elif isinstance(node, int) and not isinstance(node, bool) and abs(node) > _FLOAT_MAX:
            try:
                float(node)
            except OverflowError:
                return path, len(str(abs(node)))
    return None


_FLOAT_MAX = int(sys.float_info.max)
"""The largest integer a float holds exactly; one above it may still round down to it (checked by
``float()`` itself)."""


def _huge(digits: int) -> str:
    return f"an integer of {digits} digits, beyond the range of any number hil reads (a float's, ±1.8e308)"


def _too_long(exc: ValueError) -> str:
    """Python's refusal of an integer of more than 4300 digits, without its advice to the programmer."""
    return str(exc).split(";")[0]


def load_json(text: str | bytes, where: str, line: int | None = None) -> Any:
    """JSON from ``text``, nested at most :data:`MAX_NESTING` deep, every integer one a float holds
    (:func:`beyond_float`); anything else is one :class:`InputFormatError` naming ``where`` (and ``line``;
    the key in the message)."""
    try:
        value = json.loads(text)
    except RecursionError:
        raise InputFormatError(f"JSON nested deeper than {MAX_NESTING} levels", where, line) from None
    except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError is a ValueError
        raise InputFormatError(f"not JSON ({_too_long(exc)})", where, line) from None
    path = too_deep(value)
    if path is not None:
        key = f" at {_short(path)}" if path != "(top level)" else ""
        raise InputFormatError(f"JSON nested deeper than {MAX_NESTING} levels{key}", where, line)
    huge = beyond_float(value)
    if huge is not None:
        key = f" at {_short(huge[0])}" if huge[0] else ""
        raise InputFormatError(f"{_huge(huge[1])}{key}", where, line)
    return value


def load_toml(text: str, where: str, error: ErrorFactory = ConfigError) -> dict[str, Any]:
    """TOML from ``text``, nested at most :data:`MAX_NESTING` deep, every integer one a float holds
    (:func:`beyond_float`); anything else is one ``error`` whose ``where`` is ``"<where>: <key>"`` when a
    key can be named."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"not valid TOML: {exc}", where) from None
    except RecursionError:
        raise error(f"not valid TOML: nested deeper than {MAX_NESTING} levels", where) from None
    except ValueError as exc:  # an integer of more than 4300 digits: tomllib lets int()'s refusal through
        raise error(f"not valid TOML: {_too_long(exc)}", where) from None
    path = too_deep(doc)
    if path is not None:
        raise error(f"nested deeper than {MAX_NESTING} levels", f"{where}: {_short(path)}")
    huge = beyond_float(doc)
    if huge is not None:
        raise error(_huge(huge[1]), f"{where}: {_short(huge[0])}")
    return doc


def _short(path: str, keep: int = 60) -> str:
    """A key path cut to ``keep`` characters (a path 32 levels deep is long)."""
    return path if len(path) <= keep else path[:keep] + "…"


__all__ = [
    "CHUNK_BYTES",
    "FILE",
    "FOLDER",
    "MAX_COMPRESSION_RATIO",
    "MAX_DOCUMENT_BYTES",
    "MAX_LINE_BYTES",
    "MAX_MEMBERS",
    "MAX_MEMBER_BYTES",
    "MAX_NESTING",
    "PIPE",
    "LimitedReader",
    "LineSplitter",
    "beyond_float",
    "input_kind",
    "load_json",
    "load_toml",
    "read_document",
    "read_lines",
    "regular_file_if_there",
    "too_deep",
]
