"""Archives a log may come in, opened into the files they hold: zip, tar (plain, gzip, bzip2 or xz), and
an archive inside an archive (a zip holding the app's zip, a folder zipped with its export's ``.tgz``).

A phone's export reaches the host in many wrappings: the app shares a zip; a user zips the folder it
unpacked (one or two folders deep), packs it with ``tar czf`` on Linux or macOS, or mails the zip inside
another zip. Each archive becomes its members (:class:`Member`: where it is, for messages, and how to
open it), named by their path inside it, '/'-separated. What an operating system leaves beside the files
(:func:`os_litter`: ``__MACOSX/``, ``._name``, ``.DS_Store``, ``Thumbs.db``) is passed over, and the
folders that every member shares are left out of their names (an export zipped a folder or two deep
reads as the export itself).

Bounds, each an :class:`~protocol.errors.InputFormatError` naming the archive: at most
:data:`~hil.files.bounded.MAX_MEMBERS` entries; an archive inside an archive is opened to
:data:`MAX_ARCHIVE_DEPTH` levels (a deeper one is a plain member); a zip's members are read in place,
each bounded as any member is (:class:`~hil.logs.table.Container`); a tar, which cannot be read out of
order, is read once from its start and its files spooled to one temporary file (on disk, unlinked at
once), at most :data:`MAX_TAR_BYTES` in all and :data:`~hil.files.bounded.MAX_COMPRESSION_RATIO` times
its compressed size; a nested archive is spooled the same way, bounded as the member it is.
"""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import tarfile
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from hil.files.bounded import CHUNK_BYTES, MAX_MEMBER_BYTES, MAX_MEMBERS, LimitedReader, open_input
from protocol.errors import InputFormatError

MAX_ARCHIVE_DEPTH = 2
"""Archives opened one inside the other: the one given (or in the folder given) and one inside it."""
MAX_TAR_BYTES = 1 << 30
"""The most a tar may hold, decompressed (1 GiB: four of the largest members a log may have)."""
TAR_SUFFIXES = (".tar", ".tar.gz", ".tgz", ".tar.bz2", ".tbz2", ".tbz", ".tar.xz", ".txz")
ARCHIVE_SUFFIXES = (".zip", ".zip.gz", *TAR_SUFFIXES)
_MAGIC = {b"\x1f\x8b": "gzip", b"BZh": "bzip2", b"\xfd7zXZ\x00": "xz"}
"""A compressed tar's first bytes → its compression."""
_UNREADABLE = (tarfile.TarError, OSError, EOFError, zlib.error, lzma.LZMAError, ValueError)
"""What a damaged tar, or a damaged stream compressing it, raises from inside ``tarfile`` and the
decompressors."""


@dataclass(frozen=True)
class Member:
    """One file of a log: ``where`` it is (for messages: ``export.zip:Rec/Gyroscope.csv``), ``open()``
    its bytes as stored (a ``.gz`` still compressed), ``packed`` the bytes its archive compressed it to
    (None when stored as is) and ``stored`` the bytes it takes where it lies."""

    where: str
    open: Callable[[], IO[bytes]]
    packed: int | None
    stored: int


_LITTER_FOLDERS = frozenset({"__macosx", ".ds_store", "thumbs.db", "desktop.ini"})


def os_litter(name: str) -> bool:
    """Whether a member (a '/'-separated path) is what an operating system leaves beside a user's files,
    not part of a log: macOS's ``__MACOSX/`` folder and ``._name`` companions (its "Compress" puts both in
    every zip, its ``tar`` the companions), ``.DS_Store``, Windows' ``Thumbs.db`` and ``desktop.ini``."""
    parts = name.lower().split("/")
    return parts[-1].startswith("._") or any(part in _LITTER_FOLDERS for part in parts)


def archive_suffix(name: str) -> str | None:
    """The archive suffix ``name`` ends in (``.zip``, ``.tar.gz``, …; any letter case), or None."""
    lower = name.lower()
    return next((s for s in sorted(ARCHIVE_SUFFIXES, key=len, reverse=True) if lower.endswith(s)), None)


def without_suffix(name: str) -> str:
    """``name`` without its archive suffix (``Rec.tar.gz`` → ``Rec``)."""
    suffix = archive_suffix(name)
    return name[: -len(suffix)] if suffix else name


def file_member(path: Path) -> Member:
    """A file on disk as a member."""
    try:
        size = path.stat().st_size
    except OSError:
        size = 0
    return Member(str(path), lambda: open(path, "rb"), None, size)  # noqa: SIM115 — the caller closes it


def spooled_pipe(path: Path, keep: list[object]) -> tuple[IO[bytes], Member]:
    """A log given as a pipe (``hil replay <(unzip -p export.zip Gyroscope.csv)``, ``curl … | hil replay
    /dev/stdin``) read to its end into a temporary file (on disk, unlinked at once), at most
    :data:`~hil.files.bounded.MAX_MEMBER_BYTES` (an error naming it past that): a pipe is read once, from
    its start, and both an archive's reader and a log's format detection go back in it. The spool (kept
    in ``keep``) and the pipe's bytes as one member, named as a file of what its first bytes show it to
    be (:func:`piped_name`)."""
    where = str(path)
    spool = tempfile.TemporaryFile()  # noqa: SIM115 — kept open (``keep``) while the log is read
    keep.append(spool)
    source = open_input(path, InputFormatError)  # closed with the reader below; a pipe no one writes refused
    with io.BufferedReader(LimitedReader(source, where, MAX_MEMBER_BYTES)) as f:
        try:
            while piece := f.read(CHUNK_BYTES):
                spool.write(piece)
        except OSError as exc:
            raise InputFormatError(f"cannot read ({exc.strerror or exc})", where) from None
    size = spool.tell()
    spool.flush()
    spool.seek(0)
    return spool, Member(where, _range_opener(spool, 0, size), None, size)


_PIPED_SUFFIXES = ((b"MATLAB", ".mat"), (b"\x1f\x8b", ".csv.gz"), (b"[", ".json"), (b"{", ".json"))
"""A piped file's first bytes (after white space) → the suffix of the file it is: the readers tell a single
file's format by its name first (a ``.mat``, a ``.json``, a ``.csv``), and a pipe has none."""


def piped_name(pipe: Path, spool: IO[bytes]) -> str:
    """The name a piped single file is read under: the pipe's own (``63`` for ``/dev/fd/63``) with the
    suffix its first bytes show (:data:`_PIPED_SUFFIXES`; otherwise text: ``.csv``). ``spool`` is left
    at 0."""
    spool.seek(0)
    head = spool.read(64).lstrip()
    spool.seek(0)
    suffix = next((s for magic, s in _PIPED_SUFFIXES if head.startswith(magic)), ".csv")
    return pipe.name + suffix


GZIPPED_ZIP = "zip.gz"
"""The kind of a gzip stream holding a zip (:func:`kind_of`): decompressed to a temporary file, bounded as a
member is, and read as the zip (:func:`members_of`)."""


def kind_of(f: IO[bytes]) -> str | None:
    """``"zip"``, ``"tar"`` (plain or compressed), :data:`GZIPPED_ZIP` or None for the seekable stream
    ``f`` (left at 0)."""
    try:
        f.seek(0)
        head = f.read(8)
        f.seek(0)
        block = _read_at_most(_decompressed(f, head) or f, 512)
        if block[257:262] == b"ustar":  # POSIX and GNU tars, as every tool writes them
            return "tar"  # asked first: a tar whose last file is a zip ends in a zip's end record
        if head.startswith(b"\x1f\x8b") and block.startswith(b"PK\x03\x04"):
            return GZIPPED_ZIP  # the app's zip gzipped (``export.zip.gz``: a mail or backup tool's)
        f.seek(0)
        return "zip" if zipfile.is_zipfile(f) else None
    except (*_UNREADABLE, InputFormatError):
        return None
    finally:
        f.seek(0)


def _decompressed(f: IO[bytes], head: bytes) -> IO[bytes] | None:
    """``f`` decompressed when ``head`` (its first bytes) is a gzip, bzip2 or xz stream's, else None."""
    kind = next((k for magic, k in _MAGIC.items() if head.startswith(magic)), None)
    if kind == "gzip":
        return gzip.GzipFile(fileobj=f)  # type: ignore[return-value]
    if kind == "bzip2":
        return bz2.BZ2File(f)  # type: ignore[return-value]
    if kind == "xz":
        return lzma.LZMAFile(f)  # type: ignore[return-value]
    return None


def _read_at_most(f: IO[bytes], n: int) -> bytes:
    out = b""
    while len(out) < n and (piece := f.read(n - len(out))):
        out += piece
    return out


def members_of(
    f: IO[bytes], where: str, kind: str, keep: list[object], depth: int = 1
) -> tuple[str, list[tuple[str, Member]]]:
    """The members of the archive ``f`` (seekable, of ``kind`` as :func:`kind_of` tells), by their names
    inside it, litter passed over, archives inside it opened while ``depth`` < :data:`MAX_ARCHIVE_DEPTH`
    (their members named under the archive's name without its suffix), and the folders all members share
    left out of their names; and those folders (:func:`shared_folders`). ``keep`` collects what must stay
    open while the members are read."""
    if kind == GZIPPED_ZIP:
        size = f.seek(0, io.SEEK_END)
        f.seek(0)
        gzipped = Member(where, lambda: gzip.GzipFile(fileobj=f), size, size)  # type: ignore[arg-type, return-value]
        unpacked = _nested(gzipped, keep)
        if unpacked is None or unpacked[1] != "zip":
            raise InputFormatError("a gzip stream holding no readable zip", where)
        f, kind = unpacked
    found = _zip_members(f, where, keep) if kind == "zip" else _tar_members(f, where, keep)
    out: list[tuple[str, Member]] = []
    for name, member in found:
        suffix = archive_suffix(name)
        inner = _nested(member, keep) if suffix and depth < MAX_ARCHIVE_DEPTH else None
        if inner is None:
            out.append((name, member))
        else:
            prefix = without_suffix(name) + "/"
            _, held = members_of(inner[0], member.where, inner[1], keep, depth + 1)
            out += [(prefix + n, m) for n, m in held]
        if len(out) > MAX_MEMBERS:
            raise InputFormatError(f"more than {MAX_MEMBERS} files: not a phone log", where)
    shared = shared_folders([n for n, _ in out])
    return shared, [(n[len(shared) :], m) for n, m in out]


def shared_folders(names: Sequence[str]) -> str:
    """The folders every member shares, with a trailing slash ("" if none): an export zipped a folder or
    two deep (``Export/Rec/Gyroscope.csv``) reads as the export."""
    shared = ""
    while names:
        tops = {n.split("/", 1)[0] for n in names}
        if len(tops) != 1 or not all("/" in n for n in names):
            break
        top = next(iter(tops)) + "/"
        shared += top
        names = [n[len(top) :] for n in names]
    return shared


def _zip_members(f: IO[bytes], where: str, keep: list[object]) -> list[tuple[str, Member]]:
    entries = _zip_entries(f, where)
    if entries > MAX_MEMBERS:
        raise InputFormatError(f"a zip of {entries} entries (at most {MAX_MEMBERS}): not a phone log", where)
    try:
        archive = zipfile.ZipFile(f)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise InputFormatError(f"not a readable zip ({exc})", where) from None
    keep.append(archive)
    out = []
    for info in archive.infolist():
        name = zip_member_name(info.filename)
        if name.endswith("/") or os_litter(name):
            continue  # folders (``Recording\\`` too), OS litter
        packed = info.compress_size if info.compress_type != zipfile.ZIP_STORED else None
        opener = _zip_opener(archive, info)
        out.append((name, Member(f"{where}:{info.filename}", opener, packed, info.compress_size)))
    return out


def zip_member_name(filename: str) -> str:
    """A zip entry's path with '/' between its folders, as the zip format requires: Windows tools that
    break the rule (.NET Framework 4.5's ``ZipFile.CreateFromDirectory``, PowerShell 5's
    ``Compress-Archive``) write ``Recording\\Gyroscope.csv``, which ``unzip`` and 7-Zip read as a folder
    and its file, and which Python keeps as one name with a backslash in it — an export zipped a folder
    deep that way was "not a recognised log". No phone's file name holds a backslash."""
    return filename.replace("\\", "/")


def _zip_opener(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> Callable[[], IO[bytes]]:
    return lambda: archive.open(info)


def _zip_entries(f: IO[bytes], where: str) -> int:
    """The number of entries a zip's end record declares (read before its directory is parsed, so that a
    directory of millions of entries is refused rather than held)."""
    try:
        f.seek(0)
        end = zipfile._EndRecData(f)  # type: ignore[attr-defined]  # stable since Python 2
    except OSError as exc:
        raise InputFormatError(f"cannot read ({exc.strerror})", where) from None
    return int(end[zipfile._ECD_ENTRIES_TOTAL]) if end else 0  # type: ignore[attr-defined]


def _tar_members(f: IO[bytes], where: str, keep: list[object]) -> list[tuple[str, Member]]:
    """A tar's files, read once from its start (see the module docstring), spooled to a temporary file."""
    f.seek(0)
    head = f.read(8)
    f.seek(0)
    size = f.seek(0, io.SEEK_END)
    f.seek(0)
    unpacked = _decompressed(f, head)
    packed = size if unpacked is not None else None
    stream = io.BufferedReader(LimitedReader(unpacked or f, where, MAX_TAR_BYTES, packed), 1 << 16)
    spool = tempfile.TemporaryFile()  # noqa: SIM115 — kept open (``keep``) while the log is read
    keep.append(spool)
    out: list[tuple[str, Member]] = []
    entries = 0
    try:
        with tarfile.open(fileobj=stream, mode="r|") as tar:
            for info in tar:
                entries += 1
                if entries > MAX_MEMBERS:
                    what = f"a tar of more than {MAX_MEMBERS} entries: not a phone log"
                    raise InputFormatError(what, where)
                name = info.name.lstrip("/").removeprefix("./")
                if not info.isfile() or os_litter(name):
                    continue  # folders, links, devices; OS litter
                source = tar.extractfile(info)
                if source is None:
                    continue
                offset = spool.seek(0, io.SEEK_END)
                while piece := source.read(CHUNK_BYTES):
                    spool.write(piece)
                opener_of = _range_opener(spool, offset, info.size)
                out.append((name, Member(f"{where}:{name}", opener_of, None, info.size)))
    except InputFormatError:
        raise
    except _UNREADABLE as exc:
        raise InputFormatError(f"not a readable tar archive ({type(exc).__name__}: {exc})", where) from None
    spool.flush()
    return out


def _range_opener(spool: IO[bytes], offset: int, size: int) -> Callable[[], IO[bytes]]:
    return lambda: io.BufferedReader(_Range(spool, offset, size), 1 << 16)


class _Range(io.RawIOBase):
    """``size`` bytes of ``spool`` from ``offset``, read with their own position (several may be open)."""

    def __init__(self, spool: IO[bytes], offset: int, size: int) -> None:
        super().__init__()
        self._spool, self._pos, self._end = spool, offset, offset + size

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: memoryview) -> int:  # type: ignore[override]
        view = memoryview(buffer).cast("B")
        n = min(len(view), self._end - self._pos)
        if n <= 0:
            return 0
        self._spool.seek(self._pos)
        data = self._spool.read(n)
        view[: len(data)] = data
        self._pos += len(data)
        return len(data)


def _nested(member: Member, keep: list[object]) -> tuple[IO[bytes], str] | None:
    """The archive ``member`` is, spooled to a temporary file (bounded as the member it is), and its kind;
    None when it is not one (a damaged zip: left a plain member, whose reader names it)."""
    spool = tempfile.TemporaryFile()  # noqa: SIM115 — kept open (``keep``) while the log is read
    try:
        source = member.open()
    except (OSError, zipfile.BadZipFile, NotImplementedError, RuntimeError) as exc:
        raise InputFormatError(f"cannot read ({exc})", member.where) from None
    with io.BufferedReader(LimitedReader(source, member.where, MAX_MEMBER_BYTES, member.packed)) as f:
        try:
            while piece := f.read(CHUNK_BYTES):
                spool.write(piece)
        except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise InputFormatError(f"damaged ({exc})", member.where) from None
    kind = kind_of(spool)
    if kind is None:
        spool.close()
        return None
    keep.append(spool)
    return spool, kind
