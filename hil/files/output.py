"""Directories the project writes its results into (run directories, campaigns, replays, figures): made
where the user said, or a :class:`~protocol.errors.ConfigError` naming the path and why not — a path
under a file, one too long for the file system, a read-only place — never an ``OSError``'s traceback."""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import sys
from collections.abc import Callable
from pathlib import Path
from typing import IO

from protocol.errors import ConfigError, HilError

MAX_LABEL = 64
"""Characters of a name-derived label kept in a directory's name (a scenario's name may be long; a file
system's name is at most 255 bytes)."""
MAX_LABEL_BYTES = 200
"""Bytes (in the file system's encoding) of such a label: with a run directory's 16-byte stamp before it and
a ``-n`` after, the name stays within the 255 bytes of a file system's name — 64 letters of four bytes each
(``𠀀``, a CJK letter; ``𝐀``) are 256 bytes, and a run under a scenario named so was refused ("File name too
long") before it started."""


def make_dir(path: str | os.PathLike[str], exist_ok: bool = True) -> Path:
    """``path`` as a directory, with its parents; ``FileExistsError`` when something of that name exists
    (a directory, a file, a link to nothing) and not ``exist_ok`` (the caller picks another name); any
    other failure a ConfigError naming it — and, when a part of the path is in the way, that part and
    what it is (``--out`` through a link to nothing said "a file of that name exists" of a run directory
    that was no file, and a file or a FIFO on the way "Not a directory", naming neither)."""
    out = Path(path)
    try:
        out.mkdir(parents=True, exist_ok=exist_ok)
    except FileExistsError as exc:
        if not exist_ok and (out.is_dir() or os.path.lexists(out) and out.parent.is_dir()):
            raise  # the name itself is taken: the caller picks another
        raise _in_the_way(out, exc) from None
    except OSError as exc:
        raise _in_the_way(out, exc) from exc
    except UnicodeEncodeError:  # a ValueError: a traceback, for a name the user can fix
        raise ConfigError(
            f"cannot make this directory: its name has characters this system's file names cannot hold "
            f"({sys.getfilesystemencoding()}: set a UTF-8 locale, or choose another name)",
            str(out),
        ) from None
    return out


def _in_the_way(out: Path, refused: OSError) -> ConfigError:
    """The ConfigError of a directory ``out`` whose making the OS ``refused``: its reason (a read-only
    place, a name too long), and the first part of the path that is there but no directory (a file, a
    FIFO, a link to nothing, a loop of links), if one is, with what it is."""
    why = f"cannot make this directory: {refused.strerror or refused}"
    for part in (*reversed(out.parents), out):
        if not os.path.lexists(part):
            break  # made by mkdir, or refused for another reason (why)
        if not part.is_dir():
            return ConfigError(f"{why} ({part} is {_what_is(part)}, not a directory)", str(out))
    return ConfigError(why, str(out))


def _what_is(path: Path) -> str:
    """What ``path`` (there, no directory) is, in a few words."""
    try:
        if path.is_symlink():
            target = os.readlink(path)
            try:
                path.stat()
            except OSError as exc:
                if exc.errno == errno.ELOOP:
                    return "a loop of symbolic links"
                return f"a symbolic link to nothing, {target}"
        kind = path.stat().st_mode
    except OSError:  # gone or changed since: said as the OS would
        return "not a directory"
    for test, name in ((stat.S_ISREG, "a file"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket")):
        if test(kind):
            return name
    return "a device" if stat.S_ISCHR(kind) or stat.S_ISBLK(kind) else "not a directory"


OUTPUTS_OF: dict[str, str] = {
    "telemetry.csv": "a run's directory (hil run)",
    "events.jsonl": "a run's directory (hil run)",
    "estimates.csv": "a replay's folder (hil replay)",
    "campaign.json": "a Monte Carlo campaign's directory (hil montecarlo)",
}
"""A file name that says which command's outputs a folder holds: its own (the one every such folder has)."""


def refuse_others_outputs(out_dir: Path, own: str, writing: str) -> None:
    """A ConfigError naming ``out_dir`` when it holds another command's outputs (:data:`OUTPUTS_OF`, any
    but ``own``, the file this command's folders are known by) — ``writing`` says what was to go there.
    ``hil replay --out`` or ``hil montecarlo --out`` given a run's directory replaced its summary.json with
    their own, beside its telemetry and events, exit 0: the run's record was lost, and ``hil report``
    showed that run with every figure "-"."""
    for name, whose in OUTPUTS_OF.items():
        if name != own and os.path.lexists(out_dir / name):
            raise ConfigError(
                f"{whose} is here ({name}): {writing} would replace its summary.json beside it; give "
                "another --out",
                str(out_dir),
            )


def safe_label(label: str) -> str:
    """``label`` as a part of a directory's name: characters other than letters, digits and ``-_.`` — and
    letters the file system's encoding cannot hold (a scenario named ``cubesat-ü`` under a C locale: a
    ``UnicodeEncodeError``'s traceback before the run) — replaced, at most :data:`MAX_LABEL` of them and
    :data:`MAX_LABEL_BYTES` of their bytes (whole letters)."""
    encoding = sys.getfilesystemencoding()
    safe = "".join(c if (c.isalnum() and _nameable(c, encoding)) or c in "-_." else "_" for c in label)
    return fit_name(safe[:MAX_LABEL], MAX_LABEL_BYTES) or "run"


NAME_MAX_BYTES = 255
"""The longest name of one file or folder, in bytes (Linux's ``NAME_MAX``; most file systems')."""


def fit_name(name: str, limit: int = NAME_MAX_BYTES) -> str:
    """``name`` cut at its end, in whole letters, to ``limit`` bytes as the file system names files
    (:func:`os.fsencode`): a name made of a user's (a log's, a scenario's) with a prefix or suffix added
    can pass the file system's limit, and the command then failed on "File name too long"."""
    while len(os.fsencode(name)) > limit:
        name = name[:-1]
    return name


def _nameable(char: str, encoding: str) -> bool:
    """Whether ``char`` can be part of a file name in the file system's ``encoding``."""
    try:
        char.encode(encoding)
    except UnicodeEncodeError:
        return False
    return True


class OutputError(HilError, OSError):
    """A result file (a run's telemetry, events or summary) that the operating system refused to write: a
    full disk (ENOSPC), a file-size limit (EFBIG), an I/O error, a directory removed or replaced under the
    run. Says which file and why; an :class:`OSError` too, with the refusal's ``errno``, so a caller that
    handles the OS's errors handles it."""

    def __init__(self, path: str | os.PathLike[str], error: OSError) -> None:
        super().__init__(error.errno, f"cannot write {path}: {error.strerror or error}")
        self.path = Path(path)

    def __str__(self) -> str:
        return str(self.strerror)

    def __reduce__(self) -> tuple[object, ...]:
        # OSError's own pickles (errno, strerror) into __init__(path, error): a figure drawn in a forked
        # process (hil.plots.forked) sends its refusal back pickled
        return (_output_error, (str(self.path), self.errno, self.strerror))


def _output_error(path: str, errno: int | None, strerror: str | None) -> OutputError:
    error = OutputError(path, OSError(errno, strerror))
    error.strerror = strerror  # already "cannot write PATH: why"
    return error


def write_file(path: str | os.PathLike[str], text: str) -> None:
    """``text`` as the whole of ``path``, in UTF-8 (what every reader of the project's files reads, and TOML
    and JSON are: written in the locale's encoding, a run's copy of its scenario under a C or Latin-1
    locale was a ``UnicodeEncodeError``'s traceback for the ``°`` of a shipped scenario, or a file its
    readers refused); an :class:`OutputError` naming it when the OS refuses."""
    try:
        Path(path).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise OutputError(path, exc) from exc


def replace_file(path: str | os.PathLike[str], write: Callable[[IO[bytes]], object]) -> Path:
    """``write(f)`` into a new temporary beside ``path`` (same directory, a name of its own), then renamed
    over ``path``: a reader never sees half a file, and whatever is at ``path`` — a symbolic link planted
    there (``plots/delta.png -> /tmp/victim``) — is replaced, never followed or written through. A refusal
    (a directory at ``path``, a read-only directory, a full disk) is an :class:`OutputError` naming
    ``path``, no temporary left behind."""
    import tempfile  # here: not among the imports before a run's first tick (~2.5 ms with shutil)

    out = Path(path)
    tmp: str | None = None
    try:
        # the name cut in bytes: 64 letters of four bytes and mkstemp's additions passed 255 bytes
        fd, tmp = tempfile.mkstemp(prefix=f".{fit_name(out.name, 200)}.", suffix=".tmp", dir=out.parent)
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), 0o666 & ~_umask())  # mkstemp's 0600: readable as any file hil writes
            write(f)
            f.flush()
            os.fsync(f.fileno())  # the data on the disk before the name points at it (a power cut between)
        os.replace(tmp, out)
        tmp = None
    except OSError as exc:
        if isinstance(exc, HilError):
            raise
        raise OutputError(out, exc) from exc
    finally:
        if tmp is not None:  # whatever stopped the write (a drawing's own error too): no temporary left
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    return out


def _umask() -> int:
    """This process's umask, read without changing it (``os.umask`` sets it: a race with other threads);
    Linux says it in /proc/self/status, elsewhere the usual 022 is assumed."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return 0o022
