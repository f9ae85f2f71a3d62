"""When the board made what the host reads, in the host's time, sans-IO (every call takes the host's ``now``).

Why: the host takes a Telemetry's receive time for the time it describes, and judges by it whether the
board is seen live. That holds while the host keeps reading. A host that itself stopped reading — its
process paused or swapped out, its reader thread held, its port reopened — finds the board's backlog
waiting: frames from the start of its pause (a pty keeps the oldest bytes and the board drops the rest
once it is full). Stamped with the time they were read, they were shown as live, though the host had been
blind for the whole pause, and the run's record showed no stale episode at all.

So a *late* read — one that ends more than :data:`PROMPT_READ_S` after the host's previous read ended
(``waiting_since``) — puts the session *behind*, and what it reads from then on is dated by the board's
clock: a sample's uptime plus the least ``receive time - uptime`` among the samples of the last
:data:`WINDOW_S` before it fell behind (the link's lowest latency, as a network time client takes its
lowest-delay sample; over a window, so that a board's clock running slow or fast against the host's is
followed), never later than its receive time and never earlier than the read before the late one. One
read does not always take the whole backlog (a pty hands it over 4 KiB at a time), so the session stays
behind until the read after one in which a sample so dated came within :data:`PROMPT_READ_S` of its
receive time, or until its reads have been prompt for :data:`CATCH_UP_S` (a board whose clock drifted
over the pause). A boot that began while the host was behind (a board that reset during its pause) has
no offset yet: its samples in that read are dated by the earliest they can have been made — the last read
before the pause plus their uptime — and from the next read on as a first boot's. While the host reads
promptly, a sample is dated by its receive time, as before: a board whose clock falls behind the host's
for a while (an emulator under load catching up its pacing) never has fresh frames taken for old.
"""

from __future__ import annotations

from collections import deque

PROMPT_READ_S = 0.1
"""s: a read that ends within this of the previous read's end is prompt; its frames are dated by their
receive time (at most this late: well under the host's 0.25 s stale bound)."""

WINDOW_S = 2.0
"""s of host time over which the least ``receive time - uptime`` is taken (the last sample is kept past it
through a pause)."""

CATCH_UP_S = 0.5
"""s of prompt reads after which the session is caught up whatever the board's clock says (a backlog is
read in milliseconds; a clock that drifted over a long pause must not keep fresh frames dated old)."""


class MadeAt:
    """See the module docstring."""

    def __init__(self) -> None:
        # (host time, receive time - uptime) of prompt samples, offsets increasing: the front is the least
        self._window: deque[tuple[float, float]] = deque()
        self._behind_since: float | None = None  # the end of the last read before the host fell behind
        self._prompt_since: float | None = None  # behind, but reading promptly since then
        self._caught_up = False  # behind, and a sample of this read came within PROMPT_READ_S of its read
        self._new_boot = False  # a boot seen to begin after the host's first (its window still empty)

    def forget_boot(self) -> None:
        """A new boot: its clock starts again, the offsets with it."""
        self._window.clear()
        self._new_boot = True

    def read(self, now: float, waiting_since: float | None) -> None:
        """Bytes read at ``now``; the host's previous read ended at ``waiting_since`` (None: not known, or
        the first read)."""
        if self._caught_up:  # from this read on (the rest of the last one was dated by the clock too)
            self._behind_since = self._prompt_since = None
            self._caught_up = False
        if waiting_since is not None and now - waiting_since > PROMPT_READ_S:
            if self._behind_since is None:
                self._behind_since = waiting_since
            self._prompt_since = None
        elif self._behind_since is not None:
            if self._prompt_since is None:
                self._prompt_since = now
            elif now - self._prompt_since >= CATCH_UP_S:
                self._behind_since = self._prompt_since = None

    def sample(self, uptime_s: float, now: float) -> float:
        """The host time a sample of the board's clock (``uptime_s``, read at ``now``) was made."""
        window = self._window
        behind = self._behind_since
        if behind is not None and not window and self._new_boot:
            # A new boot read late (the board reset while the host was not reading): its clock has no
            # offset on the host's yet. It began after the host's last prompt read, so its sample was made
            # no earlier than that plus its uptime: dated so, never as read — its backlog, seconds old,
            # was shown live, and so dated it ended the session's being behind for the rest of the read.
            # For this read only: from the next one on its samples are dated as a first boot's (by their
            # receive time, anchoring its offset) — a bound that may lie seconds early must not keep a
            # restarted board's fresh telemetry stale for good.
            self._caught_up = True
            return min(now, behind + uptime_s)
        if behind is None or not window:  # not behind, or the first boot's first sample: no clock to go by
            self._behind_since = self._prompt_since = None
            self._caught_up = False
            offset = now - uptime_s
            while window and window[-1][1] >= offset:
                window.pop()
            window.append((now, offset))
            self._new_boot = False
            while len(window) > 1 and window[0][0] < now - WINDOW_S:
                window.popleft()
            return now
        made = min(now, max(behind, uptime_s + window[0][1]))
        self._caught_up = self._caught_up or made >= now - PROMPT_READ_S
        return made
