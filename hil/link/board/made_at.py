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
over the pause), or until the samples come as fast as the board makes them (:data:`STEADY_S`). A boot
that began while the host was behind (a board that reset during its pause) has
no offset yet: its samples are dated by the earliest they can have been made — the last read before the
pause plus their uptime — by the same rules for as long as the session stays behind (every chunk of its
backlog, not only the first: the second 4 KiB of a restarted board's backlog was dated as read, seconds
old and shown live), and once caught up as a first boot's (by their receive time, anchoring its offset).
While the host reads promptly, a sample is dated by its receive time, as before: a board whose clock falls
behind the host's for a while (an emulator under load catching up its pacing) never has fresh frames
taken for old.

A link that comes back (:meth:`MadeAt.link_up`) is no late read: a port opened anew holds nothing older
than its opening (the client dates the new connection's first read from it), and a pause before the loss
says nothing of the new connection's frames — a restarted board's first samples after a reconnect were
dated by the read before the loss, seconds before the board was even started again.
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


STEADY_S = 0.03
"""s: behind, the least ``receive time - uptime`` among the samples read since (the latest a sample can
have been made sets an upper bound on the board's offset) that no later read lowered by more than
:data:`STEADY_TOLERANCE_S` for this long, the sample read now as fresh: the samples come as fast as the
board makes them — the backlog is read (a chunk of it holds more of the board's time than passed on the
host's between reads, and lowers the least by that). Why: a board that restarted while the host was
paused has no offset yet; its samples are dated by the earliest they can have been made (the host's last
read before the pause plus their uptime), and its fresh telemetry, made milliseconds before it was read,
was dated as old as the time between the host's pause and the board's restart — shown stale for
:data:`CATCH_UP_S` after the host was back."""

STEADY_TOLERANCE_S = 0.01
"""s: how far the least ``receive time - uptime`` may still go down and be steady: the link's latency
jitter, and a board clock running fast against the host's (10 % of :data:`STEADY_S`)."""


class MadeAt:
    """See the module docstring."""

    def __init__(self) -> None:
        # (host time, receive time - uptime) of prompt samples, offsets increasing: the front is the least
        self._window: deque[tuple[float, float]] = deque()
        self._behind_since: float | None = None  # the end of the last read before the host fell behind
        self._prompt_since: float | None = None  # behind, but reading promptly since then
        self._caught_up = False  # behind, and a sample of this read came within PROMPT_READ_S of its read
        self._new_boot = False  # a boot seen to begin after the host's first (its window still empty)
        # behind: (host time it was set, the least receive time - uptime of the samples read since)
        self._least: tuple[float, float] | None = None

    def forget_boot(self) -> None:
        """A new boot: its clock starts again, the offsets with it."""
        self._window.clear()
        self._new_boot = True
        self._least = None  # the old boot's samples are of another clock

    def link_up(self) -> None:
        """The link is (re)opened: whatever the host was behind on came over the connection before it
        (the new one's reads are dated from its opening); the offsets stay (the board may be the same
        boot: the session tells a new one by :meth:`forget_boot`)."""
        self._behind_since = self._prompt_since = None
        self._caught_up = False
        self._least = None

    def read(self, now: float, waiting_since: float | None) -> None:
        """Bytes read at ``now``; the host's previous read ended at ``waiting_since`` (None: not known, or
        the first read)."""
        if self._caught_up:  # from this read on (the rest of the last one was dated by the clock too)
            self._behind_since = self._prompt_since = None
            self._caught_up = False
            self._least = None
        if waiting_since is not None and now - waiting_since > PROMPT_READ_S:
            if self._behind_since is None:
                self._behind_since = waiting_since
            self._prompt_since = None
            self._least = None  # late again: what was read before the pause says nothing of what waits now
        elif self._behind_since is not None:
            if self._prompt_since is None:
                self._prompt_since = now
            elif now - self._prompt_since >= CATCH_UP_S:
                self._behind_since = self._prompt_since = None
                self._least = None

    def sample(self, uptime_s: float, now: float) -> float:
        """The host time a sample of the board's clock (``uptime_s``, read at ``now``) was made."""
        window = self._window
        behind = self._behind_since
        if behind is None or not (window or self._new_boot):
            # not behind, or the first boot's first sample: dated by its receive time, anchoring the offset
            self._behind_since = self._prompt_since = None
            self._caught_up = False
            self._least = None
            offset = now - uptime_s
            while window and window[-1][1] >= offset:
                window.pop()
            window.append((now, offset))
            self._new_boot = False
            while len(window) > 1 and window[0][0] < now - WINDOW_S:
                window.popleft()
            return now
        # Behind: dated by the board's clock. A new boot read late (the board reset while the host was not
        # reading) has no offset on the host's yet: it began after the host's last prompt read, so its
        # sample was made no earlier than that plus its uptime — the earliest it can have been made, never
        # as read (its backlog, seconds old, was shown live). Caught up as any other: a sample so dated
        # within PROMPT_READ_S of its read, or CATCH_UP_S of prompt reads (a bound seconds early must not
        # keep a restarted board's fresh telemetry stale for good); then dated as a first boot's.
        offset = window[0][1] if window else behind
        made = min(now, max(behind, uptime_s + offset))
        self._caught_up = self._caught_up or made >= now - PROMPT_READ_S or self._steady(uptime_s, now)
        return made

    def _steady(self, uptime_s: float, now: float) -> bool:
        """Whether, behind, the samples now come as fast as the board makes them (:data:`STEADY_S`): the
        least ``now - uptime_s`` read since falling behind has held for that long."""
        latest = now - uptime_s  # the board's offset is at most this: the sample was made by its read
        least = self._least
        if least is None or latest < least[1] - STEADY_TOLERANCE_S:
            self._least = (now, latest)  # fresher than any before: what came before was a backlog
            return False
        if latest < least[1]:
            self._least = (least[0], latest)
        # and this sample as fresh as the freshest: a host reading slower than the board writes (a chunk
        # of its backlog holding less of the board's time than passed between reads) falls further behind
        return latest <= least[1] + STEADY_TOLERANCE_S and now - least[0] >= STEADY_S
