"""Reading and writing the calibration package's text files: typed errors that name the file, atomic
writes (a reader never sees half a calibration file) and an exclusive lock for a read-modify-write (two
writers of one file never lose each other's change)."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import secrets
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

from hil.files.bounded import MAX_DOCUMENT_BYTES, read_document
from protocol.errors import ConfigError, HilError


def read_text(path: str | os.PathLike[str], error: Callable[[str, str], HilError]) -> str:
    """The UTF-8 text of ``path``, at most :data:`~hil.files.bounded.MAX_DOCUMENT_BYTES` (a calibration
    file or a bench CSV is a few kB); ``error(detail, path)`` is raised when it is missing, unreadable,
    not text or larger (:func:`hil.files.bounded.read_document`)."""
    return read_document(path, error, limit=MAX_DOCUMENT_BYTES)


def shown(text: str) -> str:
    """``text`` as it can be shown anywhere (a plot's title, a message): a byte a file name or an argument
    held that is not UTF-8 (a surrogate escape, ``\\udcff``) is written as its escape. matplotlib's text
    layout refused such a string with a ``TypeError`` (a traceback after the fit)."""
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


def check_text(text: str, where: str, error: Callable[[str, str], HilError]) -> str:
    """``text``, if a UTF-8 file can hold it; else ``error(detail, where)``. A name given on the command
    line or a path with a byte that is not UTF-8 (``--name $'\\xff'``, a bench CSV named so) reaches Python
    as a surrogate escape, which no calibration file can store: its write raised a ``UnicodeEncodeError``
    (a traceback, and a temporary file left) — after a board was calibrated, in ``hil calibrate unit``."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise error(
            f"'{shown(text)}' is not UTF-8 text (character {exc.start}): a calibration file cannot hold it",
            where,
        ) from None
    return text


def write_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file renamed over it; creates the directory.
    :class:`ConfigError` naming the file if it cannot be written.

    The temporary file's name is unique to this write (``.<name>.<random>.tmp`` in the same folder, so the
    rename stays atomic): with one fixed ``<name>.tmp`` two writers at once wrote into, renamed and
    removed each other's temporary file. It is made with ``O_EXCL`` and the process's umask, as the
    file itself would be."""
    out = Path(path)
    tmp: Path | None = None
    try:  # encoded before the temporary file is made: a text no UTF-8 file holds leaves none behind
        data = text.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise ConfigError(f"cannot write: character {exc.start} is not UTF-8 text", str(path)) from None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = _temporary(out)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())  # the data on the disk before the name points at it (a power cut between)
        os.replace(tmp, out)
    except OSError as exc:
        if tmp is not None and tmp.is_file():  # written but not renamed (the target a folder): not left
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise ConfigError(f"cannot write: {exc.strerror or exc}", str(path)) from exc
    return out


def _temporary(out: Path) -> tuple[int, Path]:
    """A new file beside ``out`` with a name no other writer has, open for writing: its descriptor and
    path. :func:`tempfile.mkstemp` would make it mode 0600 whatever the umask (a calibration file that
    only its writer could read)."""
    while True:
        tmp = out.with_name(f".{out.name}.{secrets.token_hex(6)}.tmp")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:  # 48 random bits taken: draw again
            continue


def lock_path(path: str | os.PathLike[str]) -> Path:
    """The lock file :func:`locked` holds for ``path``: beside it, ``.<name>.lock`` (there only while a
    writer holds it)."""
    out = Path(path)
    return out.with_name(f".{out.name}.lock")


@contextlib.contextmanager
def locked(path: str | os.PathLike[str], where: str | None = None) -> Iterator[Path]:
    """Hold an exclusive lock on ``path`` (``fcntl.flock`` on :func:`lock_path`) for a read-modify-write:
    another :func:`locked` of the same file waits until this one ends. Without it two ``hil calibrate
    fit`` runs into one file each read it, added their unit and wrote it back: the second write lost the
    first's unit. Makes ``path``'s folder. The lock file is removed on the way out; a waiter that then
    holds a lock on the removed file sees it is no longer the one at :func:`lock_path` and locks again
    (so two writers never hold locks on two different files). :class:`ConfigError` naming ``where``
    (default: the path) when the folder or the lock file cannot be made. Yields ``path``."""
    out = Path(path)
    said = where if where is not None else str(out)
    lock = lock_path(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX)
                held, now = os.fstat(fd), os.stat(lock)
            except FileNotFoundError:  # removed by the writer before us while we waited: lock again
                os.close(fd)
                continue
            except BaseException:
                os.close(fd)
                raise
            if (held.st_dev, held.st_ino) == (now.st_dev, now.st_ino):
                break
            os.close(fd)  # a new lock file made after ours was removed: lock that one
    except OSError as exc:
        why = exc.strerror or exc
        if exc.errno == errno.ENOLCK:
            why = "the file system takes no locks"
        raise ConfigError(f"cannot lock {out} ({lock}): {why}", said) from exc
    try:
        yield out
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)  # while still held: a waiter then sees its lock file is gone
        os.close(fd)


def check_writable(path: str | os.PathLike[str], where: str | None = None) -> Path:
    """Refuse, before any work (a board driven, a sweep run), a file that :func:`write_atomic` could not
    write or that reading would hang on: ``path`` exists but is not a regular file (a folder, a FIFO — a
    read of which waits for a writer for ever —, a device), or its folder cannot be made or written (a
    parent that is a regular file, a read-only folder). :class:`ConfigError` naming ``where`` (default:
    the path). Nothing is created."""
    out = Path(path)
    said = where if where is not None else str(out)
    if out.exists() or out.is_symlink():
        if not out.is_file():
            kind = "a folder" if out.is_dir() else "not a regular file (a FIFO, a device or a socket)"
            raise ConfigError(f"cannot write {out}: {kind}", said)
    folder = out.parent
    while not folder.exists():
        if folder.is_symlink():  # a dangling link: mkdir would fail
            raise ConfigError(f"cannot write {out}: {folder} is a broken link", said)
        folder = folder.parent
    if not folder.is_dir():
        raise ConfigError(f"cannot write {out}: {folder} is not a folder", said)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"cannot write {out}: the folder {folder} is not writable", said)
    return out


def check_distinct(
    outputs: Mapping[str, str | os.PathLike[str]], inputs: Mapping[str, str | os.PathLike[str]] | None = None
) -> None:
    """Refuse, before any work, an output of a command (option → path) that is the file of another of its
    outputs or of one of the ``inputs`` it reads: ``hil calibrate fit -o cal.png --plot cal.png`` saved the
    plot, wrote the calibration file over it and said it wrote both; a ``--plot`` naming a bench CSV wrote
    the picture over the data it came from. One file is the same path after links are followed, or the
    same inode (a hard link). :class:`ConfigError` naming the output and the other option."""
    seen: dict[tuple[int, int] | Path, str] = {
        _identity(Path(p)): option for option, p in (inputs or {}).items()
    }
    for option, path in outputs.items():
        key = _identity(Path(path))
        if key in seen:
            raise ConfigError(f"{path} is the file of {seen[key]} too: give each its own file", option)
        seen[key] = option


def _identity(path: Path) -> tuple[int, int] | Path:
    """What makes two paths one file: its device and inode if it exists, else its absolute path with the
    links of its existing part followed."""
    try:
        st = path.stat()
    except OSError:
        return path.resolve()
    return (st.st_dev, st.st_ino)
