"""Link statistics: what the host sent and received, what went wrong, how long commands took.

:class:`LinkStats` is a frozen snapshot (``BoardClient.stats()``); :meth:`LinkStats.as_dict` flattens it
into JSON/CSV-friendly ``name -> number`` pairs for a run's ``summary.json`` and telemetry log.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, fields

import numpy as np


@dataclass(frozen=True, slots=True)
class RoundTrips:
    """Reliable-command round trips (first send → Ack/Nack), milliseconds, over the newest samples."""

    count: int = 0
    p50_ms: float = math.nan
    p99_ms: float = math.nan
    max_ms: float = math.nan


class RttRing:
    """The newest ``capacity`` round-trip times (s) and their percentiles."""

    def __init__(self, capacity: int = 1024) -> None:
        self._samples: deque[float] = deque(maxlen=capacity)
        self.total = 0

    def add(self, seconds: float) -> None:
        self._samples.append(seconds)
        self.total += 1

    def summary(self) -> RoundTrips:
        if not self._samples:
            return RoundTrips()
        ms = np.asarray(self._samples) * 1e3
        p50, p99 = np.percentile(ms, [50, 99])
        return RoundTrips(self.total, float(p50), float(p99), float(ms.max()))


@dataclass
class SessionCounters:
    """What the host side did (mutable; the session updates it)."""

    frames_out: int = 0  # frames written (every kind, retries included)
    setpoints_sent: int = 0
    setpoints_coalesced: int = 0  # replaced by a newer one before their send slot (newest wins)
    setpoints_dropped: int = 0  # given while no session was up (link down, handshaking)
    heartbeats_sent: int = 0
    handshakes: int = 0  # HelloReplies accepted
    link_losses: int = 0
    reconnects: int = 0
    resets: int = 0  # board resets detected
    # reconnects that reached another or an incompatible board, or a port another host holds (never commanded)
    boards_refused: int = 0
    silences: int = 0
    events_dropped: int = 0  # the event queue was full (nobody drained it)
    unknown_board_states: int = 0  # a Heartbeat.state that is no BoardState
    calibration_answers: int = 0  # CalibrationData fragments from the board answered
    telemetry_misfits: int = 0  # Telemetry for another number of units or channels than the board's: dropped
    telemetry_repeats: int = 0  # Telemetry identical to the one held (repeated, replayed): dropped
    board_leaps: int = 0  # Telemetry/Heartbeat whose uptime or frame count leapt ahead: dropped
    board_reanchors: int = 0  # leaps so consistent that the first counts heard were the absurd ones
    # Telemetry/Heartbeat a little behind the newest of the other kind (overtaken on CAN): taken, no reset
    board_samples_overtaken: int = 0
    # Telemetry/Heartbeat behind what the same boot already said (replayed, held back on the way): dropped
    board_samples_stale: int = 0
    board_logs_unlogged: int = 0  # board Log frames beyond BOARD_LOGS_PER_S: reported as events, not logged
    echoes: int = 0  # the host's own frames come back (the port echoes what is written): dropped
    host_frames: int = 0  # frames only a host sends that this host did not write (another host): dropped


@dataclass(frozen=True)
class LinkStats:
    """A snapshot of the link. ``bad_frames`` by ``BadFrameReason`` value; ``seq_gaps`` and ``duplicates``
    over the board's frames alone (the host's own come back are ``counters.echoes``); ``board_*`` are the
    board's own counters of what it received from the host (from its latest Telemetry); ``transport``
    holds the transport's own counters (CAN segments, ...)."""

    bytes_in: int
    bytes_out: int
    frames_in: int
    bad_frames: dict[str, int]
    resyncs: int
    seq_gaps: int
    duplicates: int
    commands_sent: int
    retries: int
    acked: int
    nacked: int
    failed: int
    late_answers: int
    unmatched_answers: int
    rtt: RoundTrips
    counters: SessionCounters
    board_rx_frames: int | None = None
    board_rx_bad: int | None = None
    board_seq_gaps: int | None = None
    transport: dict[str, int] = field(default_factory=dict)
    superseded: int = 0  # commands not retried: a newer one set the same thing (an Arm after a Disarm)

    @property
    def bad_frames_total(self) -> int:
        return sum(self.bad_frames.values())

    def as_dict(self) -> dict[str, float | int | None]:
        """Flat ``name -> number`` pairs (``bad_frames.crc``, ``rtt.p99_ms``, ``transport.rx_incomplete``)."""
        out: dict[str, float | int | None] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, dict):
                out.update({f"{f.name}.{k}": v for k, v in value.items()})
            elif isinstance(value, (RoundTrips, SessionCounters)):
                out.update({f"{f.name}.{g.name}": getattr(value, g.name) for g in fields(value)})
            else:
                out[f.name] = value
        out["bad_frames_total"] = self.bad_frames_total
        return out
