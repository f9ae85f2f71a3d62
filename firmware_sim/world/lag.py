"""How far a real-time world falls behind the board's clock, and why: sans-IO, fed by the world's thread.

The world's thread (:class:`firmware_sim.world.WorldStreamer`) tells :class:`LagMonitor` after each pass
how far behind the board's clock the world is, how much wall time passed and how much of it the thread
spent stepping. *Start-up* lasts until the world first catches up with the clock (its lag under the
threshold); what lags there is kept apart (``startup_lag_s``) and never counted as an episode — the
world's kernels are loaded and its first batch stepped before the board's clock starts
(:func:`firmware_sim.world.load_kernels`), so a start-up lag is small, but a first pass may still come
late. After start-up every rise of the lag over the threshold is one *episode* (it ends when the lag is
back under half the threshold), and the warning says what lags (the plant and the phone it carries) and
why, from the episode's own figures:

* the thread was busy stepping for most of the episode (``work ≥ 80 %`` of the wall time): stepping the
  plant is slower than real time on this machine;
* it was not: the thread was kept waiting — the CPU given to other processes, or the board's lock held
  by its server.
"""

from __future__ import annotations

from dataclasses import dataclass

LAG_WARNING_S = 0.1
"""s: a world this far behind the board's clock is in a lag episode."""
BUSY_FRACTION = 0.8
"""Of an episode's wall time, the share spent stepping above which the plant itself is too slow."""
WARNED_EPISODES = 3
"""Episodes warned about one by one; later ones are counted (and the last warning says so)."""


@dataclass
class LagStats:
    """``max_lag_s``: the furthest the world fell behind after start-up (s); ``startup_lag_s``: the
    furthest during start-up; ``episodes``: lag episodes after start-up; ``started``: start-up is over."""

    max_lag_s: float = 0.0
    startup_lag_s: float = 0.0
    episodes: int = 0
    started: bool = False


class LagMonitor:
    """Lag episodes of a world behind its board's clock; see the module docstring."""

    def __init__(self, threshold_s: float = LAG_WARNING_S) -> None:
        self.threshold_s = threshold_s
        self.stats = LagStats()
        self._in_episode = False
        self._elapsed = 0.0  # wall s and stepping s since the lag was last under the threshold
        self._work = 0.0

    def observe(self, lag_s: float, elapsed_s: float, work_s: float) -> str | None:
        """One pass of the world's thread: the world ``lag_s`` behind the board's clock after it, the pass
        took ``elapsed_s`` of wall time, ``work_s`` of it stepping. A warning to log when this pass begins
        an episode (None otherwise)."""
        stats = self.stats
        if not stats.started:
            stats.startup_lag_s = max(stats.startup_lag_s, lag_s)
            stats.started = lag_s < self.threshold_s
            return None
        stats.max_lag_s = max(stats.max_lag_s, lag_s)
        self._elapsed += elapsed_s
        self._work += work_s
        if self._in_episode:
            if lag_s < self.threshold_s / 2:
                self._in_episode = False
                self._elapsed = self._work = 0.0
            return None
        if lag_s < self.threshold_s:
            self._elapsed = self._work = 0.0
            return None
        self._in_episode = True
        stats.episodes += 1
        if stats.episodes > WARNED_EPISODES:
            return None
        busy = self._work / self._elapsed if self._elapsed > 0 else 0.0
        if busy >= BUSY_FRACTION:
            why = (
                f"its thread was stepping {busy:.0%} of the time: stepping the plant is slower than real "
                "time on this machine"
            )
        else:
            why = (
                f"its thread was stepping only {busy:.0%} of the time: it was kept waiting (the CPU busy "
                "with other processes, or the board's lock held by its server)"
            )
        more = " (further episodes are counted, not reported)" if stats.episodes == WARNED_EPISODES else ""
        return (
            f"the world (the plant and the phone it carries) runs {lag_s * 1e3:.0f} ms behind the board's "
            f"clock, lag episode {stats.episodes}: {why}; the phone comes late meanwhile, the board's link "
            f"is not affected; lockstep runs are unaffected{more}"
        )
