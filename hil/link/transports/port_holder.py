"""Who holds a serial port's exclusive lock: the process a "port busy" error names.

A host opens its port with an exclusive ``flock`` (pyserial's ``exclusive=True``), so a second host is
refused instead of handshaking with — and so disarming — the board under the first. The refusal is only
useful if it says whom to stop, so this module finds the holder, Linux only, read-only, best effort:

1. ``/proc/locks``: a ``FLOCK`` line gives the locking pid and the locked file as ``major:minor:inode``
   (hex device numbers), matched against ``stat()`` of the device the path resolves to. That pid is the
   one that *took* the lock; it is confirmed by step 2 before it is named (it may have been reused);
2. a process holds the lock if one of its ``/proc/<pid>/fd`` is that device and the descriptor's
   ``fdinfo`` shows the lock. Every process is looked at this way when the named pid is gone (the
   process that took the lock exited and a child that inherited the descriptor holds it now) or lives in
   another pid namespace (shown as 0). A process that merely has the device open (``firmware-sim`` keeps
   the pty's slave open, without a lock) is not it.

Anything unreadable (another user's ``/proc`` entries, no ``/proc`` at all) just means "not found".
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

_PROC = Path("/proc")
_CMDLINE_MAX = 200  # characters of a holder's command line quoted in an error message


def find_holder(device: str) -> tuple[int, str | None] | None:
    """``(pid, command line or None)`` of the process holding ``device``'s flock, or None if not found."""
    try:
        st = os.stat(device)
    except OSError:
        return None
    key = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
    named = [pid for pid in _flock_pids(key) if pid > 0]
    # The pids /proc/locks names first, each checked (a pid may have been reused since it took the lock);
    # every other process only if none of them holds it.
    for pid in itertools.chain(named, (pid for pid in _all_pids() if pid not in named)):
        if _holds(pid, st.st_dev, st.st_ino, key):
            return pid, _cmdline(pid)
    return None


def _all_pids() -> list[int]:
    try:
        return [int(entry.name) for entry in os.scandir(_PROC) if entry.name.isdigit()]
    except OSError:
        return []


def _lock_key(fields: list[str]) -> tuple[int, tuple[int, int, int]] | None:
    """``(pid, (major, minor, inode))`` of a FLOCK line's fields after its ``N:`` index (None otherwise:
    POSIX locks, OFD locks, a waiter's ``->`` line, anything unparsable)."""
    if len(fields) < 5 or fields[0] != "FLOCK":
        return None
    try:
        major, minor, inode = fields[4].split(":")
        return int(fields[3]), (int(major, 16), int(minor, 16), int(inode))
    except ValueError:
        return None


def _flock_pids(key: tuple[int, int, int]) -> list[int]:
    try:
        text = (_PROC / "locks").read_text()
    except OSError:
        return []
    pids = []
    for line in text.splitlines():
        parsed = _lock_key(line.split()[1:])
        if parsed is not None and parsed[1] == key:
            pids.append(parsed[0])
    return pids


def _holds(pid: int, dev: int, ino: int, key: tuple[int, int, int]) -> bool:
    """Whether one of ``pid``'s descriptors is ``dev``/``ino`` and carries its flock (per its fdinfo)."""
    fd_dir = _PROC / str(pid) / "fd"
    try:
        fds = os.listdir(fd_dir)
    except OSError:
        return False  # gone, or another user's
    for fd in fds:
        try:
            st = os.stat(fd_dir / fd)
            if (st.st_dev, st.st_ino) != (dev, ino):
                continue
            info = (_PROC / str(pid) / "fdinfo" / fd).read_text()
        except OSError:
            continue
        for line in info.splitlines():
            if line.startswith("lock:"):
                parsed = _lock_key(line.split()[2:])  # "lock:", "N:", then the /proc/locks fields
                if parsed is not None and parsed[1] == key:
                    return True
    return False


def _cmdline(pid: int) -> str | None:
    try:
        raw = (_PROC / str(pid) / "cmdline").read_bytes()
    except OSError:
        return None
    text = " ".join(raw.replace(b"\0", b" ").decode(errors="replace").split())  # one line, even for -c "..."
    if not text:
        return None  # a zombie or a kernel thread
    return text if len(text) <= _CMDLINE_MAX else text[: _CMDLINE_MAX - 1] + "…"
