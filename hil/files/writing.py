"""Whether a directory is still being written: its writer holds an exclusive ``flock`` on the directory
itself for as long as it writes (:class:`WriterLock`; a run holds its run directory's from its making to its
``summary.json``), and the kernel lets go of it when the process ends, however it ends — a ``kill -9``
too. A reader that follows the directory (``hil gcs``) asks :func:`writer_holds`: a lock held is a writer
alive, however long it has been silent (a stalled run); a lock once held and now free, without the
writer's last file, is a writer gone (killed, crashed) — it will write nothing more.

The reader's question takes a shared lock for a moment (``LOCK_SH | LOCK_NB``, let go at once): it never
waits, and a writer taking its lock at that moment tries again (:data:`TRIES`). A file system without
locks (some network ones) goes without: the writer holds none, and :func:`writer_holds` says it cannot
tell (None).
"""

from __future__ import annotations

import fcntl
import logging
import os
import time
from pathlib import Path

logger = logging.getLogger(__name__)

TRIES = 50  # a writer's attempts at its lock (a reader's question holds it for microseconds)
TRY_PAUSE_S = 0.002


class WriterLock:
    """An exclusive lock on ``path`` (a directory) while it is written: :meth:`release` (idempotent) when
    the writing is done; the OS lets go of it when the process ends. Never raises: a directory whose lock
    cannot be had (a file system without locks; a reader holding it throughout) is written without, and
    said in the log."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._fd: int | None = None
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_DIRECTORY)
        except OSError as exc:
            logger.warning("%s: not locked while written: %s", self.path, exc.strerror or exc)
            return
        for _ in range(TRIES):
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                time.sleep(TRY_PAUSE_S)
                continue
            except OSError as exc:
                logger.info("%s: not locked while written: %s", self.path, exc.strerror or exc)
                break
            self._fd = fd
            return
        else:
            logger.warning("%s: not locked while written: its lock is held by another process", self.path)
        os.close(fd)

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """The writing is done (after the writer's last file): readers see the lock free."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)  # closing the descriptor lets go of its lock

    def __enter__(self) -> WriterLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def writer_holds(path: str | os.PathLike[str]) -> bool | None:
    """Whether a writer holds ``path``'s lock (:class:`WriterLock`) now; None when it cannot be told (the
    directory gone, a file system without locks)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return None
    finally:
        os.close(fd)  # lets go of the shared lock, if taken
    return False
