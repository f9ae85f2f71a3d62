"""A recorded phone log as a run's phone (``recording://``): its samples released at their own pace on the
run's clock.

``hil replay LOG --port URL`` drives a board with the controller's output while the estimator runs over a
recording; the runtime then takes its phone samples from here instead of a phone or the world. Times are
moved onto the run's clock (the log's first sample at the run's origin), so the estimator, the controller,
the telemetry and the log's ground truth share one time axis; on a :class:`~hil.timing.clock.WallClock` the
log plays in real time, on a :class:`~hil.timing.clock.LockstepClock` as fast as the CPU allows.

The log is the one ``hil replay`` read, windowed and configured the estimator for
(:attr:`~hil.link.sources.base.SourceContext.recording`): the URL names the source, not a file to read
again.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil import so3
from hil.estimation.admission import JUMP_S
from hil.estimation.sensors import SensorKind, SensorLog, SensorSample
from hil.link.sources.base import EventWriter, GroundTruth, PhoneSource, SourceContext
from protocol.errors import ConfigError

Array = NDArray[np.float64]

RECORDING_URL = "recording://"
"""The URL of the recording a run plays (``hil replay``)."""
END_TICKS = 2
"""The run ends this many control ticks after the estimator task has drained the recording's last sample
(:meth:`RecordedSource.start`): the tick after it sees the recording exhausted."""


def play(url: str, context: SourceContext) -> RecordedSource:
    """The ``recording://`` source: the run's recording (``hil replay``), played from the run's origin."""
    if context.recording is None:
        raise ConfigError(f"{url}: a recording is played by `hil replay LOG --port URL`", "--phone")
    stop_after_s = END_TICKS / context.scenario.loop.control_rate_hz
    return RecordedSource(context.recording, url, stop_after_s, context.write_event)


def release_times(t: Array) -> Array:
    """When each of one stream's samples is released, on the log's clock: in the stream's recorded order,
    each at the latest time recorded up to it — a sample's time counted no later than the next finite
    time after it — (a NaN time, whose reading the host drops and counts, at the last finite one; -inf
    before any: at once). A sample whose time went back (a clock that jumped back, a resumed recording)
    goes out in its place, after the later ones, as a live phone would send it, for the host's admission
    to judge — sorted by its own time it was slipped in among them, the recording's two stretches
    interleaved into one estimate (the replay without ``--port`` drops them, warned). A stamp more than
    :data:`~hil.estimation.admission.JUMP_S` ahead of the sample after it (a corrupt time: 11 days on, 5 s
    on) is released with that next sample, as the phone sent it, and the host's admission drops it as a
    ``future`` stray: counted as the latest time, it held every later sample of its stream back until then
    (the phone lost). Nearer, it is due at its own time (never released early)."""
    if not len(t):
        return t
    finite = np.flatnonzero(np.isfinite(t))
    after = np.searchsorted(finite, np.arange(len(t)), side="right")  # the next finite sample's index
    nxt = np.full(len(t), np.inf)
    has = after < len(finite)
    nxt[has] = t[finite[after[has]]]
    stray = t - nxt > JUMP_S  # ahead of the next sample by more than the host takes as one stream
    release = np.fmax.accumulate(np.where(stray, nxt, t))  # fmax: a NaN keeps the running maximum
    return np.where(np.isnan(release), -np.inf, release)


class RecordedSource(PhoneSource):
    """``log``'s samples, every sensor's in one release order (:func:`release_times`), on the run's clock
    from its origin (s; the log's first sample is due then). Nothing is due before :meth:`start` sets the
    origin; the run ends one estimator period and ``stop_after_s`` (s) after the last sample
    (``replay_start`` in ``events.jsonl`` says when)."""

    def __init__(self, log: SensorLog, url: str, stop_after_s: float, write_event: EventWriter) -> None:
        self.log = log
        self.url = url
        self._stop_after_s = stop_after_s
        self._write_event = write_event
        # columnar, every sensor's in one release order (release time, then kind; stable: each stream's own
        # order kept, release_times), a SensorSample made only as it is drained. One object per sample for
        # the whole log cost ~350 B a sample (10x the log's arrays: ~360 MB more for an hour's three 100 Hz
        # sensors) before the run even began
        streams = list(log.streams.values())
        times = np.concatenate([np.asarray(st.t, dtype=float) for st in streams])
        kinds = np.concatenate([np.full(len(st.t), int(st.kind), dtype=np.int8) for st in streams])
        release = np.concatenate([release_times(np.asarray(st.t, dtype=float)) for st in streams])
        order = np.lexsort((kinds, release))
        self._times = times[order]  # on the log's clock, as recorded (a NaN stays one: the host drops it)
        self._kinds = kinds[order]
        self._xyz = np.concatenate([np.asarray(st.xyz, dtype=float).reshape(-1, 3) for st in streams])[order]
        self._log_times = release[order]  # sorted: what drain searches
        self._next = 0
        self._play_from(math.inf)
        truth = log.truth
        self._truth_log_t = None if truth is None else np.asarray(truth.t, dtype=float)
        self._truth_R = None if truth is None else np.asarray(truth.R, dtype=float)
        # valid where the rotation is finite (motion-capture occlusions are NaN); a trial's *evaluate* mask
        # says where to score a filter, not where the truth holds
        R = self._truth_R
        self._truth_ok = None if R is None else np.all(np.isfinite(R), axis=(1, 2))

    def _play_from(self, origin: float) -> None:
        self.origin = origin
        self._shift = origin - self.log.start

    def start(self, origin: float) -> float:
        """Play the log from run time ``origin`` (s); returns the run time at which the run ends: one
        estimator period (:attr:`rate_hz`'s: the estimator task drains the last sample at most that long
        after it is due) and ``stop_after_s`` after the last sample. Without the estimator's period a log
        slower than the control ticks' ``stop_after_s`` (a 20 Hz log, 0.05 s, against two 50 Hz ticks,
        0.04 s) could reach the run's end before its last sample was drained: the run, slewed and held,
        ended "time limit (the slew never started)", status 1, its recording never exhausted."""
        self._play_from(origin)
        rate_hz = self.rate_hz
        drained_within_s = 1.0 / rate_hz if rate_hz > 0 else 0.0  # 0 Hz: the scenario's rate (no period)
        until = self.end + drained_within_s + self._stop_after_s
        self._write_event(origin, "replay_start", log=self.log.source, until=until)
        return until

    @property
    def rate_hz(self) -> float:
        """The log's fastest sensor's rate (Hz, from its median sample period): the estimator task's."""
        return 1.0 / min(s.median_period() for s in self.log.streams.values())

    @property
    def end(self) -> float:
        """The run time (s) of the log's last sample."""
        return self.log.end + self._shift

    @property
    def exhausted(self) -> bool:
        return self._next >= len(self._log_times)

    @property
    def released(self) -> int:
        return self._next

    def drain(self, now: float) -> list[SensorSample]:
        """The samples due by run time ``now`` (s) that were not handed out yet."""
        stop = int(np.searchsorted(self._log_times, now - self._shift, side="right"))
        start = self._next
        if stop <= start:
            return []
        self._next = stop
        times = (self._times[start:stop] + self._shift).tolist()
        kinds = self._kinds[start:stop].tolist()
        xyz = self._xyz[start:stop].tolist()
        return [
            SensorSample(t, SensorKind(k), (x, y, z))
            for t, k, (x, y, z) in zip(times, kinds, xyz, strict=True)
        ]

    def truth(self, now: float) -> GroundTruth | None:
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
        return GroundTruth(R0 @ so3.exp(step * ((now - t[k]) / dt)), step / dt)

    def close(self) -> None:
        """Nothing to release: the log was read before the run and stays the caller's."""

    def report(self) -> dict[str, dict[str, Any]]:
        return {"replay": {"samples_released": self.released}}
