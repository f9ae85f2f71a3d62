"""A recorded phone log as a live source: its samples released at their own pace on a run's clock.

``hil replay LOG --port URL`` drives a board with the controller's output while the estimator runs over a
recording; the runtime then takes its phone samples from here instead of a phone or the world. Times are
moved onto the run's clock (the log's first sample at ``origin``), so the estimator, the controller, the
telemetry and the log's ground truth share one time axis; on a :class:`~hil.timing.clock.WallClock` the log
plays
in real time, on a :class:`~hil.timing.clock.LockstepClock` as fast as the CPU allows.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil import so3
from hil.estimation.sensors import SensorLog, SensorSample

Array = NDArray[np.float64]


class RecordedSource:
    """``log``'s samples, every sensor's in one time order, on the run's clock from ``origin`` (s; the log's
    first sample is due then). Nothing is due before :meth:`start` sets the origin."""

    def __init__(self, log: SensorLog, origin: float = math.inf) -> None:
        self.log = log
        every = (s for stream in log.streams.values() for s in stream.samples())
        self._samples = sorted(every, key=lambda s: (s.t_s, int(s.kind)))  # on the log's clock
        self._log_times = np.array([s.t_s for s in self._samples])
        self._next = 0
        self.start(origin)
        truth = log.truth
        self._truth_log_t = None if truth is None else np.asarray(truth.t, dtype=float)
        self._truth_R = None if truth is None else np.asarray(truth.R, dtype=float)
        # valid where the rotation is finite (motion-capture occlusions are NaN); a trial's *evaluate* mask
        # says where to score a filter, not where the truth holds
        R = self._truth_R
        self._truth_ok = None if R is None else np.all(np.isfinite(R), axis=(1, 2))

    def start(self, origin: float) -> None:
        """Play the log from run time ``origin`` (s)."""
        self.origin = origin
        self._shift = origin - self.log.start

    @property
    def end(self) -> float:
        """The run time (s) of the log's last sample."""
        return self.log.end + self._shift

    @property
    def exhausted(self) -> bool:
        return self._next >= len(self._samples)

    @property
    def released(self) -> int:
        return self._next

    def drain(self, now: float) -> list[SensorSample]:
        """The samples due by run time ``now`` (s) that were not handed out yet."""
        stop = int(np.searchsorted(self._log_times, now - self._shift, side="right"))
        shift = self._shift
        out = [SensorSample(s.t_s + shift, s.kind, s.xyz) for s in self._samples[self._next : stop]]
        self._next = max(stop, self._next)
        return out

    def truth(self, now: float) -> tuple[Array, Array] | None:
        """The log's ground truth at run time ``now``: attitude (3, 3) body → ENU by geodesic interpolation
        between the neighbouring truth samples, and body rate (3,) rad/s from their difference; None without
        truth, outside it, or next to a missing truth sample (a motion-capture occlusion)."""
        t, now = self._truth_log_t, now - self._shift  # on the log's clock
        if t is None or len(t) < 2 or not (t[0] <= now <= t[-1]):
            return None
        assert self._truth_R is not None and self._truth_ok is not None
        k = min(int(np.searchsorted(t, now, side="right")) - 1, len(t) - 2)
        if not (self._truth_ok[k] and self._truth_ok[k + 1]):
            return None
        dt = t[k + 1] - t[k]
        if dt <= 0:
            return None
        R0, R1 = self._truth_R[k], self._truth_R[k + 1]
        step = so3.log(R0.T @ R1)
        return R0 @ so3.exp(step * ((now - t[k]) / dt)), step / dt
