"""Invariants checked on what a faulted run recorded (Jepsen's way: a checker over the recorded history,
not over what the code meant to do): its events, its rows, its summary and the board's own pulse record
(:class:`hil.runtime.record.RunRecorder`), against the faults injected into it (:class:`InjectedFault`).

==========================  ==========================================================================
invariant                   holds when
==========================  ==========================================================================
``no_crash_or_hang``        the run ended by itself (no exception) within its time limit, measured in
                            simulated time; it recorded rows and events (unless its exit says it
                            ended before it ran: an error, an abort, an interrupt)
``faults_detected``         every injected fault the host could see is reported with its cause within
                            its bound (:func:`_expectations`): in the fault journal, the events, the
                            counters; each report credited to one fault of its kind at most
``no_stale_as_live``        no row shows a board value without a live board, or telemetry older than
                            the stale bound as live; the host does not steer on a phone older than it
                            (or on none); no row shows the board LIVE while an injected fault kept it
                            silent, once the host's detection latency has passed
``safe_when_not_armed``     no pulse frame the board started drove a rotor above its safe width while
                            the board was not ARMED (the board's own pulse record)
``honest_exit``             the exit says what happened: ``completed`` only for a run that completed
                            (its last row live and ARMED, nothing open);
                            a lost board, an operator's abort or Disarm said as such; every operator
                            command in the summary; an unmet requirement says why; a run that ran its
                            time (completed, or lost with an outage still on at its end) ends then,
                            not at a later tick that saw the board again
``back_in_control``         after a recoverable fault the host is back in control within its bound,
                            re-armed only through the handshake, with the rotors at nominal speed
                            when it steers again; the requirement met, or missed for a reason the
                            record holds
==========================  ==========================================================================

A fault the host *cannot* see is not expected to be reported (it is listed with the unseen): one that
lands while the link is already down (masked by another — but for its reset, which the board tells once
it is heard again), one too short to matter (a stall no longer than the board's link timeout; one longer
is told by an ARMED board's failsafe if not by a stale view), a dead rotor ESC with no stretch of
:data:`DEAD_ESC_S` after it of the board live and ARMED, or one too close to the run's end for its bound
to pass. Faults that overlap are held to what the host can honestly tell:

* a report another fault held back is due that much later: a stall or an unplug blocks the board's
  reports; a phone gap blocks a clock jump's (told only by readings on the new clock);
* a board that went silent (a hang) and then lost its cable before its stale view was due is reported by
  the link lost, not a stale view;
* a ``burst`` spoof in a phone gap still sends readings the host takes: the gap is told from the last;
* phone clock jumps each within :data:`JUMP_S` of the next are one move of the clock to the host (told
  by readings on the new clock): the last is due a report of its own offset or of their sum, none when
  either is under a second;
* resets closer together than the board can answer are one reset to the host (:class:`_ResetEpisode`):
  a hang, brown-out or unplug before the host reported an earlier one's reset is *merged* (listed with
  the unseen), and that one report is due once the last of them has passed.

Figures come back too: each detected fault's latency and each recovery's time (fault → the host back in
control), for a campaign's percentiles — one reset report, one figure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.runtime.faults import BoardLink
from hil.runtime.record import RunRecorder
from hil.runtime.summary import DISARM_UNCONFIRMED, RAN_OUT_UNARMED

INVARIANTS = (
    "no_crash_or_hang",
    "faults_detected",
    "no_stale_as_live",
    "safe_when_not_armed",
    "honest_exit",
    "back_in_control",
)
BOARD_KINDS = ("stall", "hang", "brownout", "unplug", "noise", "dead_esc")
PHONE_KINDS = ("phone_gap", "phone_jump", "phone_spoof")
OPERATOR_KINDS = ("disarm", "arm", "abort", "slew", "hold")
FAULT_KINDS = BOARD_KINDS + PHONE_KINDS + OPERATOR_KINDS
"""Every kind of fault a run can be given (:mod:`hil.montecarlo.fault_plan` draws them)."""

SPOOF_REASONS = {
    "huge": "out_of_range",
    "nan": "non_finite",
    "saturated": "out_of_range",
    "future": "future",
    "past": "past",
    "burst": "burst",
    "duplicate": "duplicate",
}
"""The admission reason each hostile reading of ``firmware-sim --phone-spoof KIND`` is dropped for."""
SPOOF_READINGS = 3
"""Hostile readings one spoof sends at the least: one per sensor (gyroscope, accelerometer, magnetometer;
a ``burst`` many more: ``firmware_sim.world.phone_faults``), each dropped for its kind's reason."""
RESET_S = 1.5  # fault → the reset's cause reported (MCU watchdog 0.5 s, boot, handshake)
DEAD_ESC_S = 8.0  # a dead rotor ESC → reported: it coasts below 5 % of its command (τ 1.5 s), then 0.5 s
DROP_NOTE_S = 0.1  # the host notes a reason's dropped readings at most this often (hil.runtime.phone_clock)
SPUN_UP = 0.05  # rotors within this fraction of nominal when the host steers again (hil.runtime.phases)
JUMP_S = 0.2  # a phone clock jump → told: 10 readings in a row on the new clock (hil.estimation.admission)


@dataclass(frozen=True)
class InjectedFault:
    """One fault given to a run: ``kind`` (:data:`FAULT_KINDS`) at ``t`` (s, the run's clock: the board's
    in lockstep), with its ``params`` (``duration_s``, ``offset_s``, ``corrupt``, ``channel``, ``spoof``,
    ``target_deg``, ...)."""

    kind: str
    t: float
    params: Mapping[str, Any] = field(default_factory=dict)

    def describe(self) -> str:
        extra = "".join(f" {k}={_short(v)}" for k, v in self.params.items())
        return f"{self.kind}@{self.t:.3f}{extra}"


@dataclass(frozen=True)
class Bounds:
    """The bounds the checks hold a run to (s): the stale bound, the control tick, the board's telemetry
    and the phone's slowest sample period, the longest reconnection back-off, the outage bound
    (``recover_within_s``), the run's time limit (clock time, from its start), and the rotors' nominal
    speed (rad/s)."""

    stale_after_s: float
    tick_s: float
    telemetry_s: float
    phone_period_s: float
    reconnect_max_s: float
    recover_within_s: float
    time_limit_s: float
    nominal_rotor: float
    duration_s: float = math.inf
    """The run's time from the slew's start (the scenario's ``slew.duration_s``; inf: not checked)."""
    link_timeout_s: float = 0.25
    """The board's link watchdog (the scenario's ``[board] link_timeout``): a stall longer than it fails
    the board safe (an ARMED board), whatever the host's stale bound."""
    mcu_watchdog_s: float = 0.5
    """The board's MCU watchdog (``[board] mcu_watchdog``): a hung board is silent this long at least."""
    rotors_sensed: bool = True
    """Whether the board measures its rotors' response, so that a dead rotor ESC can be told at all:
    firmware-sim's emulated board does (its dead-ESC detector, and telemetry from the units' states); the
    project's C firmware (``--board firmware``) cannot — the ADK board has no sensors on the units, its
    telemetry's rotor speeds are estimates from its own outputs (firmware/src/app.c) — so there a dead rotor
    ESC is unseen, said so, not a detection missed: a campaign once flagged it as a ``faults_detected``
    violation no host could have avoided."""

    @property
    def detect_s(self) -> float:
        """Fault → a stale view or a phone gap reported: the stale bound from the last sign of life (up to
        a telemetry period or phone sample before the fault), then the next control tick, and one more."""
        return self.stale_after_s + 2 * self.tick_s + max(self.telemetry_s, self.phone_period_s) + 1e-6


@dataclass
class InvariantReport:
    """Violations by invariant (a message each; an empty list: it held), and the figures: ``detection``
    and ``recovery`` as (kind, seconds)."""

    violations: dict[str, list[str]] = field(default_factory=lambda: {name: [] for name in INVARIANTS})
    detection: list[tuple[str, float]] = field(default_factory=list)
    recovery: list[tuple[str, float]] = field(default_factory=list)
    unseen: list[str] = field(default_factory=list)  # faults the host could not see (masked, too late)

    def add(self, name: str, message: str) -> None:
        self.violations[name].append(message)

    @property
    def counts(self) -> dict[str, int]:
        return {name: len(v) for name, v in self.violations.items()}

    @property
    def ok(self) -> bool:
        return not any(self.violations.values())

    def first(self) -> str:
        """The first violation, "invariant: message" ("" when none)."""
        for name, messages in self.violations.items():
            if messages:
                return f"{name}: {messages[0]}"
        return ""


def check_run(
    faults: Sequence[InjectedFault], record: RunRecorder, bounds: Bounds, error: str | None = None
) -> InvariantReport:
    """Every invariant of the module docstring on one run; ``error`` is the exception the run raised, if
    it did."""
    report = InvariantReport()
    summary = record.summary
    _crash_or_hang(report, summary, bounds, error)
    if not summary:
        return report
    rows = record.rows()
    if not len(rows["t"]) or not record.events:
        _empty(report, summary, rows, record, error)
        return report
    end = float(rows["t"][-1])
    _stale(report, rows, bounds)
    _silent_as_live(report, faults, record, rows, bounds, end)
    _pulses(report, record)
    _detected(report, faults, record, rows, bounds, end)
    _honest(report, faults, summary, record, rows, bounds, end)
    _back(report, faults, summary, record, rows, bounds, end)
    return report


# --------------------------------------------------------------------------- no crash, no hang
def _crash_or_hang(
    report: InvariantReport, summary: Mapping[str, Any], bounds: Bounds, error: str | None
) -> None:
    if error is not None:
        report.add("no_crash_or_hang", f"the run raised {error}")
    exit_reason = str(summary.get("exit", ""))
    if exit_reason.startswith("error:"):
        report.add("no_crash_or_hang", f"the run ended in an error: {exit_reason}")
    sim_s = summary.get("sim_s")
    limit = bounds.time_limit_s + float(summary.get("suspended_s") or 0.0)
    if sim_s is not None and sim_s > limit + 1.0:
        report.add(
            "no_crash_or_hang", f"the run took {sim_s:.1f} s of simulated time, its limit {limit:.1f} s"
        )
    if not summary:
        report.add("no_crash_or_hang", "the run left no summary")


ENDED_BEFORE_RUNNING = ("error:", "aborted:", "interrupted")
"""Exits that may come before the run's first tick: a run that says so may have no rows, no events."""


def _empty(
    report: InvariantReport,
    summary: Mapping[str, Any],
    rows: Mapping[str, np.ndarray],
    record: RunRecorder,
    error: str | None,
) -> None:
    """A summary with no rows or no events: every run that ran a tick writes both (its events from the
    connection on, a row each tick), so only a run that ended before it ran — an error (judged as such
    by :func:`_crash_or_hang`), an abort, an interrupt — may leave them empty; any other exit is a run
    whose record was lost, and nothing it claims can be checked."""
    exit_reason = str(summary.get("exit", ""))
    if error is not None or exit_reason.startswith(ENDED_BEFORE_RUNNING):
        return
    missing = " and ".join(
        what for what, n in (("no rows", len(rows["t"])), ("no events", len(record.events))) if not n
    )
    report.add("no_crash_or_hang", f"the run recorded {missing}, yet its exit says {exit_reason!r}")


# --------------------------------------------------------------------------- stale shown as live
def _stale(report: InvariantReport, rows: Mapping[str, np.ndarray], bounds: Bounds) -> None:
    link, age, values = rows["board_link"], rows["tel_age_ms"], rows["board_values"]
    t = rows["t"]
    blind = (link != BoardLink.LIVE) & values
    if blind.any():
        k = int(np.argmax(blind))
        report.add(
            "no_stale_as_live",
            f"row at t={t[k]:.3f} s: board values without a live board ({blind.sum()} rows)",
        )
    old = (link == BoardLink.LIVE) & ~(age <= bounds.stale_after_s * 1e3 + 1e-6)
    if old.any():
        k = int(np.argmax(old))
        report.add("no_stale_as_live", f"row at t={t[k]:.3f} s: live with telemetry {age[k]:.0f} ms old")
    phone_age, phase = rows["phone_age_ms"], rows["phase"]
    steering = (phase == 1) | (phase == 2)  # slew or hold: the host commands the board
    stale_phone = steering & ~(phone_age <= (bounds.stale_after_s + bounds.tick_s) * 1e3 + 1e-6)
    if stale_phone.any():
        k = int(np.argmax(stale_phone))
        report.add(
            "no_stale_as_live", f"row at t={t[k]:.3f} s: steering on a phone {phone_age[k]:.0f} ms old"
        )


BROWNOUT_S = 0.3
"""A brown-out's silence at the least: the pack collapses this long (``--brownout-at``), in reset."""


def _silence_s(fault: InjectedFault, b: Bounds) -> float:
    """How long ``fault`` keeps the board silent at the least (s): a stall's or an unplug's duration, a
    hang until the MCU's watchdog resets it, a brown-out while the pack is down."""
    if fault.kind in ("stall", "unplug"):
        return float(fault.params.get("duration_s", 0.0))
    return b.mcu_watchdog_s if fault.kind == "hang" else BROWNOUT_S


def _silence_end(fault: InjectedFault, faults: Sequence[InjectedFault], b: Bounds) -> float:
    """When the board's silence from ``fault`` ends at the latest (s): its own silence's end, or — for a
    hang — sooner when another reset lands meanwhile (a brown-out 2 ms after a hang boots the board 0.3 s
    later, not at the hang's watchdog: a CI draw's honest run was failed for the board live again)."""
    ends = fault.t + _silence_s(fault, b)
    if fault.kind != "hang":
        return ends
    for other in faults:
        if other is not fault and other.kind in ("hang", "brownout") and fault.t <= other.t < ends:
            ends = min(ends, other.t + _silence_s(other, b))
    return ends


def _silent_as_live(
    report: InvariantReport,
    faults: Sequence[InjectedFault],
    record: RunRecorder,
    rows: Mapping[str, np.ndarray],
    b: Bounds,
    end: float,
) -> None:
    """No row shows the board LIVE while the board was silent (the faults, not the host's own flags):
    from a stall, unplug, hang or brown-out the host could see (the board live when it came), once its
    stale bound has passed from the last telemetry and a tick more, to the end of the board's silence."""
    t, link = rows["t"], rows["board_link"]
    episodes = _reset_episodes(faults, record.summary.get("faults", []), b)
    merged = [f for ep in episodes for f in ep.merged]
    sessions = _session_starts(record)
    outages = record.summary.get("outages") or []
    for f in faults:
        if (
            f.kind not in LINK_BLOCKING
            or f.t > end
            or any(f is m for m in merged)
            or _masked(f, rows, b, sessions, outages)
        ):
            continue  # a merged hang waited for a boot: no silence of its own
        lo = f.t + b.stale_after_s + b.telemetry_s + b.tick_s
        live = (t > lo + 1e-9) & (t < _silence_end(f, faults, b) - 1e-9) & (link == BoardLink.LIVE)
        if live.any():
            k = int(np.argmax(live))
            report.add(
                "no_stale_as_live",
                f"row at t={t[k]:.3f} s shows the board LIVE {t[k] - f.t:.3f} s into {f.describe()}'s "
                "silence",
            )


# --------------------------------------------------------------------------- safe pulses
def _pulses(report: InvariantReport, record: RunRecorder) -> None:
    if not record.pulses_recorded:
        return
    if record.unsafe_frames:
        report.add(
            "safe_when_not_armed",
            f"{record.unsafe_frames} frames drove a rotor above the safe pulse while not ARMED; "
            + "; ".join(record.unsafe_examples),
        )
    if record.frames_missed:
        report.add(
            "safe_when_not_armed", f"{record.frames_missed} pulse frames were not checked (record overrun)"
        )


# --------------------------------------------------------------------------- detection
@dataclass(frozen=True)
class _Expect:
    """What reports a fault: journal kinds (any of them) and a reset cause, within ``bound`` s."""

    kinds: tuple[str, ...]
    bound: float
    cause: str | None = None
    reason: str | None = None


def _expectations(fault: InjectedFault, b: Bounds) -> list[_Expect]:
    """What must report ``fault`` (empty: a fault the host is not expected to see)."""
    p = fault.params
    kind = fault.kind
    if kind == "stall":
        if p["duration_s"] <= b.link_timeout_s:
            return []  # shorter than the board's link watchdog: the link carries again before anything is due
        # an ARMED board fails safe once its link timeout passes (told when the link carries again), and
        # the host's stale bound may pass first
        due = max(b.detect_s, p["duration_s"] + b.telemetry_s + 2 * b.tick_s + 1e-6)
        return [_Expect(("stale", "failsafe", "link_lost"), due)]
    if kind == "hang":
        return [_Expect(("stale",), b.detect_s), _Expect(("reset",), RESET_S, cause="WATCHDOG")]
    if kind == "brownout":
        return [_Expect(("reset",), RESET_S, cause="BROWN_OUT")]
    if kind == "unplug":
        return [
            _Expect(("link_lost",), 2 * b.tick_s + 1e-6),
            _Expect(("reset",), p["duration_s"] + b.reconnect_max_s + RESET_S, cause="POWER_ON"),
        ]
    if kind == "dead_esc":
        if p["channel"] % 2 == 0:
            return []  # a gimbal servo: told dead only once asked to turn (the requirement's why says so)
        return [_Expect(("esc_dead", "rotor_not_following"), DEAD_ESC_S)]
    if kind == "phone_gap":
        if p["duration_s"] < _gap_seen_s(b):
            return []
        return [_Expect(("phone_gap",), b.detect_s)]
    if kind == "phone_jump":
        told = _clock_moved(p["offset_s"])
        return [_Expect(told, JUMP_S)] if told else []
    if kind == "phone_spoof":
        reason = SPOOF_REASONS[p["spoof"]]
        if reason == "duplicate":
            return []  # the merger's business (counted), not a fault of its own
        return [_Expect(("readings_dropped",), 2 * b.tick_s + DROP_NOTE_S, reason=reason)]
    return []


def _detected(
    report: InvariantReport,
    faults: Sequence[InjectedFault],
    record: RunRecorder,
    rows: Mapping[str, np.ndarray],
    bounds: Bounds,
    end: float,
) -> None:
    journal = record.summary.get("faults", [])
    episodes = _reset_episodes(faults, journal, bounds)
    sessions = _session_starts(record)
    outages = record.summary.get("outages") or []
    credited: dict[tuple[str, int], list[InjectedFault]] = {}  # (kind, journal index) → faults credited
    for fault in faults:
        if fault.kind in OPERATOR_KINDS:
            continue
        expected = _expectations(fault, bounds)
        if fault.kind == "phone_jump":
            if _jumped_again(fault, faults):
                report.unseen.append(
                    f"{fault.describe()} (merged: the phone's clock jumped again within {JUMP_S} s, before "
                    "readings on this clock could tell it)"
                )
                continue
            expected = _jumps_expected(fault, faults)
        if fault.kind == "phone_gap" and expected:
            quiet = _gap_quiet_from(fault, faults, bounds)
            if quiet is None:
                report.unseen.append(
                    f"{fault.describe()} (split: a burst's readings, some accepted, left no stretch of it "
                    "long enough to tell)"
                )
                continue
            expected = [_Expect(e.kinds, e.bound + quiet, e.cause, e.reason) for e in expected]
        if not expected:
            if fault.kind in ("stall", "phone_gap") and fault.t <= end:
                report.unseen.append(f"{fault.describe()} (too short: nothing is due before it ends)")
            continue
        if fault.kind == "stall" and fault.params["duration_s"] < _stale_stall_s(bounds):
            # longer than the board's link timeout, shorter than the host's stale bound: only an ARMED
            # board's failsafe tells it
            k = int(np.searchsorted(rows["t"], fault.t)) - 1
            if k < 0 or rows["board_state"][k] != 2:
                report.unseen.append(f"{fault.describe()} (too short for a stale view, the board not ARMED)")
                continue
        dead_due = _dead_esc_due(fault, rows, end) if fault.kind == "dead_esc" else None
        if dead_due is not None and not bounds.rotors_sensed:
            report.unseen.append(
                f"{fault.describe()} (the board does not sense its rotors: its telemetry's speeds are "
                "estimates from its outputs, and no dead ESC can be told by it)"
            )
            continue
        if dead_due is not None:
            if math.isinf(dead_due):
                report.unseen.append(
                    f"{fault.describe()} (masked: the board was not live and ARMED for "
                    f"{DEAD_ESC_S:.0f} s on end after it before the run's end)"
                )
                continue
            expected = [_Expect(e.kinds, dead_due - fault.t, e.cause, e.reason) for e in expected]
        elif _masked(fault, rows, bounds, sessions, outages):
            told = _told_though_masked(fault, expected, sessions)
            if not told:
                report.unseen.append(f"{fault.describe()} (masked: the host could not see the board then)")
                continue
            expected = told  # its silence hidden by the one already on; its reset told all the same
        episode = next((ep for ep in episodes if any(fault is f for f in (ep.leader, *ep.merged))), None)
        if episode is not None and fault is not episode.leader:
            report.unseen.append(
                f"{fault.describe()} (merged: it came before the host had reported "
                f"{episode.leader.describe()}'s reset; a board that resets again before it has answered "
                "shows the host one reset)"
            )
            # its reset is the episode's (the leader's, to its due); a hang that waited for the main loop
            # has no silence of its own to be stale
            expected = [] if fault.kind == "hang" else [e for e in expected if "reset" not in e.kinds]
        # the board tells only its last reset's cause: one reset for several unchecks it, none else
        resets = episode is not None and bool(episode.merged)
        for e in expected:
            members: tuple[InjectedFault, ...] = ()
            if episode is not None and episode.merged and "reset" in e.kinds:
                e = _Expect(e.kinds, max(e.bound, episode.due - fault.t), e.cause, e.reason)
                members = episode.merged  # already in the episode's due: not a blocked link besides
            others = [f for f in faults if not any(f is m for m in members)]
            blocked = 0.0 if fault.kind == "dead_esc" else _blocked_s(fault, others, bounds, e.bound)
            if fault.kind == "phone_jump":
                blocked += _phone_silent_s(fault, faults, e.bound)
            kinds = e.kinds
            if "stale" in kinds and "link_lost" not in kinds and _unplugged_first(fault, faults, bounds):
                kinds = (*kinds, "link_lost")
            e = _Expect(kinds, e.bound + blocked, None if resets else e.cause, e.reason)
            if fault.t + e.bound > end:
                report.unseen.append(f"{fault.describe()} (too close to the end for its {e.bound:.2f} s)")
                continue
            lo = fault.t - 1e-9
            unit = fault.params["channel"] // 2 if fault.kind == "dead_esc" else None
            index = next(
                (
                    k
                    for k, f in enumerate(journal)
                    if f["kind"] in e.kinds
                    and lo <= f["t"] <= fault.t + e.bound
                    and (e.cause is None or f.get("cause") == e.cause)
                    and (e.reason is None or f.get("reason") == e.reason)
                    and (f["kind"] != "rotor_not_following" or f.get("unit") == unit)
                    and _may_credit(f, fault, credited.get((fault.kind, k), []), bounds)
                ),
                None,
            )
            found = None if index is None else journal[index]
            if index is not None:
                credited.setdefault((fault.kind, index), []).append(fault)
            if found is None:
                what = (
                    "/".join(e.kinds)
                    + (f" {e.cause}" if e.cause else "")
                    + (f" ({e.reason})" if e.reason else "")
                )
                report.add(
                    "faults_detected", f"{fault.describe()}: no {what} reported within {e.bound:.2f} s"
                )
            else:
                report.detection.append((fault.kind, max(found["t"] - fault.t, 0.0)))
    noise = [
        f
        for f in faults
        if f.kind == "noise" and f.params["corrupt"] * _live_s(f, rows, faults, bounds) >= 0.01
    ]
    link = record.summary.get("link") or {}
    if noise and not (sum((link.get("bad_frames") or {}).values()) + (link.get("board_rx_bad") or 0)):
        report.add("faults_detected", f"{noise[0].describe()}: no damaged frame counted by either side")


LINK_BLOCKING = ("stall", "unplug", "hang", "brownout")


def _stale_stall_s(b: Bounds) -> float:
    """The shortest stall the host's stale bound surely sees (s): the stale bound from the last
    telemetry, then a tick, and one more."""
    return b.stale_after_s + b.telemetry_s + 2 * b.tick_s


def _may_credit(
    entry: Mapping[str, Any], fault: InjectedFault, credited: Sequence[InjectedFault], b: Bounds
) -> bool:
    """Whether a journal entry already credited to ``credited`` (faults of ``fault``'s kind) may report
    ``fault`` too: one fault each, or as many spoofs as a drop note counts readings for
    (``since_last`` over :data:`SPOOF_READINGS`, rounded up: a note of one spoof's first reading reports
    it, the one with its other two too — before, each reading counted as a spoof of its own, so a note of
    one spoof's three readings passed for three spoofs, two of them never counted; spoofs at one moment
    send their readings each) — but other faults of one kind whose effects overlap (two stalls at once, a
    second unplug while the cable is out) are one to the host, and share its one report."""
    if entry.get("kind") == "readings_dropped":  # spoofs at one moment still send readings each
        readings = max(int(entry.get("since_last") or entry.get("count") or 1), 1)
        return len(credited) < -(-readings // SPOOF_READINGS)
    if not credited:
        return True
    return any(_overlap(fault, other, b) for other in credited)


def _overlap(f: InjectedFault, g: InjectedFault, b: Bounds) -> bool:
    """Whether two faults' effects overlap in time (one without a duration: at its moment)."""

    def span(x: InjectedFault) -> float:
        if x.kind in ("hang", "brownout"):
            return _silence_s(x, b)
        return float(x.params.get("duration_s", 0.0))

    return max(f.t, g.t) <= min(f.t + span(f), g.t + span(g)) + 1e-9


def _dead_esc_due(fault: InjectedFault, rows: Mapping[str, np.ndarray], end: float) -> float | None:
    """When a dead ESC's report is due (s, the run's clock): :data:`DEAD_ESC_S` after the start of the
    first stretch of at least :data:`DEAD_ESC_S` from ``fault.t`` on in which the board was live and ARMED
    all along (only a board commanding the rotor tells it: a stall, a reset, a Disarm hold it back, never
    for good); inf when no such stretch came before the run's end; None for a gimbal servo's (no rotor
    to tell it by)."""
    if fault.params["channel"] % 2 == 0:
        return None
    t = rows["t"]
    after = t >= fault.t
    ts = t[after]
    ok = (rows["board_link"][after] == BoardLink.LIVE) & (rows["board_state"][after] == 2)
    start: float | None = None
    for k in range(len(ts)):
        if ok[k]:
            if start is None:
                start = float(ts[k]) if k else fault.t
            if ts[k] - start >= DEAD_ESC_S - 1e-9:
                return start + DEAD_ESC_S
        else:
            start = None
    return math.inf


def _blocked_s(fault: InjectedFault, faults: Sequence[InjectedFault], b: Bounds, due_s: float) -> float:
    """How long other faults kept the host from hearing the board around ``fault`` (s): a stall, an
    unplug (and its reconnection back-off) or a burst of heavy byte damage overlapping the ``due_s`` its
    report had hides the report until the link carries again."""
    extra = 0.0
    for other in faults:
        noisy = other.kind == "noise" and other.params.get("corrupt", 0.0) >= 0.005  # frames mostly lost
        if other is fault or (other.kind not in ("stall", "unplug") and not noisy):
            continue
        length = other.params.get("duration_s", 0.0) + (
            b.reconnect_max_s + RESET_S if other.kind == "unplug" else 0.0
        )
        if other.t <= fault.t + due_s + extra and other.t + length >= fault.t:
            extra += length
    return extra


def _gap_seen_s(b: Bounds) -> float:
    """The shortest phone gap the host surely tells (s): the stale bound, a sample period, two ticks."""
    return b.stale_after_s + b.phone_period_s + 2 * b.tick_s


def _gap_quiet_from(fault: InjectedFault, faults: Sequence[InjectedFault], b: Bounds) -> float | None:
    """When (s after ``fault``, a phone gap) the first stretch of it the host surely tells begins: a
    ``burst`` spoof in the gap still sends its plausible readings, the admission takes some, and the
    phone is fresh again then — the gap is told the stale bound after the burst its stretch begins at (a
    random probe's burst 0.19 s into a 0.6 s gap: the honest run told it at 0.46 s, and was failed for
    0.31 s). None when the bursts leave no stretch of :func:`_gap_seen_s`."""
    end = fault.t + fault.params.get("duration_s", 0.0)
    cuts = sorted(
        g.t
        for g in faults
        if g.kind == "phone_spoof" and g.params.get("spoof") == "burst" and fault.t < g.t < end
    )
    starts, ends = [fault.t, *cuts], [*cuts, end]
    return next((a - fault.t for a, z in zip(starts, ends, strict=True) if z - a >= _gap_seen_s(b)), None)


def _clock_moved(offset_s: float) -> tuple[str, ...]:
    """What tells a phone clock moved by ``offset_s`` (s): back a second or more, a restart; forward, a
    jump; less, nothing (its readings are within the admission's tolerance)."""
    if offset_s <= -1.0:
        return ("phone_restart",)
    if offset_s >= 1.0:
        return ("phone_jump",)
    return ()


def _jumped_again(fault: InjectedFault, faults: Sequence[InjectedFault]) -> bool:
    """Whether another phone clock jump came after ``fault`` (in the list's order at one moment) within
    :data:`JUMP_S`: the host may see no run of readings on ``fault``'s clock before it moved again."""
    order = {id(f): k for k, f in enumerate(faults)}
    return any(
        g.kind == "phone_jump"
        and (g.t, order[id(g)]) > (fault.t, order[id(fault)])
        and g.t <= fault.t + JUMP_S
        for g in faults
    )


def _jumps_expected(fault: InjectedFault, faults: Sequence[InjectedFault]) -> list[_Expect]:
    """What must report the last of phone clock jumps each within :data:`JUMP_S` of the next (``fault``):
    the host's clock anchor is the one before them all when none was told (the jumps summed: a -5 s jump
    and a +5 s one 3 ms apart move nothing — a random probe's honest run was failed for no restart),
    or the one before ``fault`` when the earlier were told in time; either report is honest, and when
    either way moves the clock by less than a second, nothing is due. A lone jump: its own offset."""
    order = {id(f): k for k, f in enumerate(faults)}
    jumps = sorted((g for g in faults if g.kind == "phone_jump"), key=lambda g: (g.t, order[id(g)]))
    k = next(i for i, g in enumerate(jumps) if g is fault)
    first = k
    while first > 0 and jumps[first].t - jumps[first - 1].t <= JUMP_S:
        first -= 1
    own = _clock_moved(fault.params["offset_s"])
    net = _clock_moved(sum(g.params["offset_s"] for g in jumps[first : k + 1]))
    if not own or not net:
        return []
    return [_Expect(tuple(dict.fromkeys((*own, *net))), JUMP_S)]


def _phone_silent_s(fault: InjectedFault, faults: Sequence[InjectedFault], due_s: float) -> float:
    """How long phone gaps kept ``fault``'s readings from the host within the ``due_s`` its report had
    (s). A clock jump is told by the readings stamped on the new clock (several in a row, over a span:
    :mod:`hil.estimation.admission`); a gap that begins before enough of them came, or a jump made during
    a gap, leaves the host nothing to tell it by until the stream resumes — the report is honest then,
    ``due_s`` after the gap's end, not ``due_s`` after the jump."""
    extra = 0.0
    for other in faults:
        if other is fault or other.kind != "phone_gap":
            continue
        end = other.t + other.params.get("duration_s", 0.0)
        if other.t <= fault.t + due_s + extra and end >= fault.t:
            extra += end - max(other.t, fault.t)
    return extra


def _unplugged_first(fault: InjectedFault, faults: Sequence[InjectedFault], b: Bounds) -> bool:
    """Whether an unplug came after ``fault`` but before a stale view of it was due: the port is gone
    then, so the host's first report of the silent board is the link lost, never a stale view (the
    stale bound runs on a link that still carries nothing; a link that is gone is reported at once)."""
    return any(
        other is not fault and other.kind == "unplug" and fault.t <= other.t <= fault.t + b.detect_s
        for other in faults
    )


RESETTING = ("hang", "brownout", "unplug")
"""The faults that reset the board (a watchdog, a brown-out, a power-on reset)."""


def _reset_due_s(fault: InjectedFault, b: Bounds) -> float:
    """Fault → its reset reported, at the latest (s): an unplug's once the cable is back and the host has
    reconnected; a hang's or a brown-out's within :data:`RESET_S`."""
    if fault.kind == "unplug":
        return fault.params.get("duration_s", 0.0) + b.reconnect_max_s + RESET_S
    return RESET_S


@dataclass(frozen=True)
class _ResetEpisode:
    """Resetting faults the host sees as one reset: the first (``leader``), those that came before the host
    had reported its reset (``merged``), and when that one report is due at the latest (``due``, s).

    A hang, brown-out or unplug that comes while an earlier one's reset has not yet been reported — the
    board hung, in reset, unpowered, or booted and not yet through the host's handshake — may well reset
    the board again (a hang that lands in reset or boot waits and hangs the main loop the moment it runs:
    ``firmware_sim.board.faults``), but the host cannot tell that reset from the first: the new boot's
    first frames carry the same uptime as the last boot's did, and the board tells only its last reset's
    cause. So the host honestly reports one reset for them all, once the last has passed; the merged
    faults' own resets are not expected of it (an unplug's link lost still is)."""

    leader: InjectedFault
    merged: tuple[InjectedFault, ...]
    due: float


def _reset_episodes(
    faults: Sequence[InjectedFault], journal: Sequence[Mapping[str, Any]], b: Bounds
) -> list[_ResetEpisode]:
    """The resetting faults grouped as the host can see them (:class:`_ResetEpisode`), in time order —
    masked ones too: a reset the host could not see still delays the one it reports."""
    order = {id(f): k for k, f in enumerate(faults)}
    resetting = sorted((f for f in faults if f.kind in RESETTING), key=lambda f: (f.t, order[id(f)]))
    episodes: list[_ResetEpisode] = []
    for fault in resetting:
        last = episodes[-1] if episodes else None
        reported = last is not None and any(
            r["kind"] == "reset" and last.leader.t <= r["t"] <= fault.t for r in journal
        )
        if last is None or reported or fault.t >= last.due:
            episodes.append(_ResetEpisode(fault, (), fault.t + _reset_due_s(fault, b)))
            continue
        if fault.kind == "hang":  # it waits for the boot after the reset before it, then hangs that
            due = max(last.due, fault.t) + RESET_S
        else:
            due = max(last.due, fault.t + _reset_due_s(fault, b))
        episodes[-1] = _ResetEpisode(last.leader, (*last.merged, fault), due)
    return episodes


def _live_s(
    fault: InjectedFault, rows: Mapping[str, np.ndarray], faults: Sequence[InjectedFault], b: Bounds
) -> float:
    """How long the host had a live board during ``fault``'s window (s) with bytes on the link: the
    board's silences (:data:`LINK_BLOCKING`, :func:`_silence_end`) left out — a stall's first 0.25 s still
    shows the board live, and noise all within a stall, damaging nothing, was expected to have damaged a
    frame (a CI draw's honest run failed)."""
    t = rows["t"]
    inside = (t >= fault.t) & (t < fault.t + fault.params.get("duration_s", 0.0))
    for other in faults:
        if other.kind in LINK_BLOCKING:
            inside &= ~((t >= other.t) & (t < _silence_end(other, faults, b)))
    if not inside.any():
        return 0.0
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return float(np.sum(rows["board_link"][inside] == BoardLink.LIVE)) * dt


def _masked(
    fault: InjectedFault,
    rows: Mapping[str, np.ndarray],
    bounds: Bounds,
    sessions: Sequence[float],
    outages: Sequence[Mapping[str, Any]],
) -> bool:
    """Whether the host could not see the board (or the phone) when ``fault`` came: the link already down
    or the view already stale (another fault), the board not yet connected, the phone not yet streaming.

    A session the host has just begun (``sessions``: its handshakes' times) shows the board not live until
    its first telemetry comes, yet nothing masks a fault then: the host counts its stale bound from the
    session's start, and sees the board's resets by their handshake — unless an outage it reported was open
    then (``outages``: a session after a reset, its silence already told). Such a fault is expected of it
    (before, the first row of every run being not yet live, a hang or a stall right after the first
    handshake was listed unseen, and a record that never told it passed).
    """
    t = rows["t"]
    k = int(np.searchsorted(t, fault.t)) - 1
    if k < 0:
        return True  # before the first row: the host was still connecting
    if fault.kind.startswith("phone"):
        age = rows["phone_age_ms"][k]
        return bool(np.isnan(age) or age > bounds.stale_after_s * 1e3)
    if rows["board_link"][k] == BoardLink.LIVE:
        return False
    start = max((s for s in sessions if s <= fault.t), default=-math.inf)
    seen = (t >= start) & (t <= fault.t) & (rows["board_link"] == BoardLink.LIVE)
    return bool(seen.any() or not fault.t - start < bounds.stale_after_s or _out_at(fault.t, outages))


def _told_though_masked(
    fault: InjectedFault, expected: Sequence[_Expect], sessions: Sequence[float]
) -> list[_Expect]:
    """What still reports a board fault that came while the host could not see the board (:func:`_masked`):
    a reset (a hang's, a brown-out's, an unplug's), whose cause the board tells by itself in its first
    frames once the host hears it again — its silence is hidden by the silence already on, its reset is
    not. (Before, nothing was expected of a hang or a brown-out in a stall or in heavy byte damage, or of
    one after the first handshake while the run's first Arm went unanswered, before its first row; a
    host that never told the reset passed.) Nothing before the first handshake (``sessions``: their
    times, s): the host may never have heard the board before it reset."""
    if fault.kind not in RESETTING or not any(s <= fault.t for s in sessions):
        return []
    return [e for e in expected if "reset" in e.kinds]


def _out_at(t: float, outages: Sequence[Mapping[str, Any]]) -> bool:
    """Whether an outage the host reported was open at ``t`` (another fault had the board out of its hands:
    a session after a reset begins within the outage the reset made, its stale view already told)."""
    return any(o["start"] <= t and (o.get("end") is None or t < o["end"]) for o in outages)


def _session_starts(record: RunRecorder) -> list[float]:
    """When the host's sessions began (s): each handshake's ``connected`` event."""
    return [float(e["t"]) for e in record.events if e["kind"] == "connected"]


# --------------------------------------------------------------------------- an honest exit
def _honest(
    report: InvariantReport,
    faults: Sequence[InjectedFault],
    summary: Mapping[str, Any],
    record: RunRecorder,
    rows: Mapping[str, np.ndarray],
    bounds: Bounds,
    end: float,
) -> None:
    exit_reason = str(summary.get("exit", ""))
    ops = summary.get("operator") or []
    sent = [o for o in ops if o["status"] not in ("refused",)]
    if exit_reason == "completed":
        if summary.get("lost"):
            report.add("honest_exit", f"completed, yet lost: {summary['lost']}")
        if summary.get("suspended_at_end") is not None:
            report.add("honest_exit", "completed, yet the operator's Disarm was in force at the end")
        if not summary.get("slew_started"):
            report.add("honest_exit", "completed, yet the slew never started")
        if any(o["command"] == "abort" for o in sent):
            report.add("honest_exit", "completed, yet the operator aborted the run")
        final = summary.get("final_disarm") or {}
        if final.get("ok") is False:
            report.add("honest_exit", f"completed, yet the final Disarm failed: {final.get('error')}")
        _completed_in_hand(report, summary, rows)
    if summary.get("lost") and not exit_reason.startswith(("lost:", "aborted:", "error:")):
        report.add("honest_exit", f"the board was lost ({summary['lost']}) but the exit says {exit_reason!r}")
    if summary.get("suspended_at_end") is not None and not exit_reason.startswith(
        ("disarmed by the operator", "lost:", "aborted:", "error:")
    ):
        report.add("honest_exit", f"disarmed by the operator at the end, yet the exit says {exit_reason!r}")
    injected = [f for f in faults if f.kind in OPERATOR_KINDS and f.t <= end]
    logged = sum(1 for o in ops if o.get("origin") == "campaign")
    if logged < len(injected):
        report.add("honest_exit", f"{len(injected)} operator commands sent, {logged} in the summary")
    requirement = summary.get("requirement") or {}
    if summary.get("slew_started") and not requirement.get("met") and not requirement.get("why"):
        report.add("honest_exit", "the requirement was not met and the summary does not say why")
    _ended_on_time(report, summary, record, bounds, end)


def _completed_in_hand(
    report: InvariantReport, summary: Mapping[str, Any], rows: Mapping[str, np.ndarray]
) -> None:
    """``completed`` only with the board in hand at the end: its last row live and ARMED, no outage and no
    phone gap still open (an open one at the end makes the run lost: :meth:`FaultJournal.open_at_end`)."""
    link, state = rows["board_link"][-1], rows["board_state"][-1]
    if link != BoardLink.LIVE or state != 2:
        view = BoardLink(int(link)).name if link in iter(BoardLink) else str(link)
        report.add(
            "honest_exit",
            f"completed, yet its last row (t={rows['t'][-1]:.3f} s) shows the board {view} "
            f"in state {state} (ARMED is 2)",
        )
    for what, episodes in (("outage", "outages"), ("phone gap", "phone_gap_list")):
        for o in summary.get(episodes) or []:
            if o.get("end") is None or o.get("recovered") is False:
                report.add("honest_exit", f"completed, yet its {what} at t={o['start']:.3f} s never ended")


def _ended_on_time(
    report: InvariantReport, summary: Mapping[str, Any], record: RunRecorder, bounds: Bounds, end: float
) -> None:
    """A run that ran its time ends within a tick of it: its slew's start, plus its duration, plus the
    operator's suspensions after that start (``suspended_after_slew_s``: those before it do not move the
    end, :meth:`hil.runtime.phases.RunPhases.time_is_up`). (One whose board was out at that moment used
    to run on to the next tick that saw it again, and could then say ``completed``.)"""
    exit_reason = str(summary.get("exit", ""))
    ran_its_time = (
        exit_reason == "completed"
        or exit_reason.startswith((DISARM_UNCONFIRMED, RAN_OUT_UNARMED))  # not in hand at its end
        or "not back when the run ended" in exit_reason
    )
    starts = [e["t"] for e in record.events if e["kind"] == "slew_start"]
    if not ran_its_time or not starts or not math.isfinite(bounds.duration_s):
        return
    # the operator's suspensions after the slew's start move its end (those before do not: phases.py)
    due = starts[0] + bounds.duration_s + float(summary.get("suspended_after_slew_s") or 0.0)
    if end > due + bounds.tick_s + 1e-6:
        report.add("honest_exit", f"the run was due to end at t={due:.3f} s and ran to {end:.3f} s")


# --------------------------------------------------------------------------- back in control
def _back(
    report: InvariantReport,
    faults: Sequence[InjectedFault],
    summary: Mapping[str, Any],
    record: RunRecorder,
    rows: Mapping[str, np.ndarray],
    bounds: Bounds,
    end: float,
) -> None:
    for o in summary.get("outages") or []:
        if o["recovered"]:
            report.recovery.append(("+".join(o["causes"]), o["duration_s"]))
        elif o["start"] + bounds.recover_within_s < end - bounds.tick_s:
            report.add(
                "back_in_control", f"outage at t={o['start']:.2f} s ({', '.join(o['causes'])}) never ended"
            )
    lost = summary.get("lost")
    open_at_end = lost is not None and "not back when the run ended" in lost
    if lost and not open_at_end and not _unrecoverable(faults, bounds, end):
        report.add("back_in_control", f"lost: {lost}")
    _rearmed_through_handshake(report, record, rows)
    _spun_up_to_steer(report, record, rows, bounds, faults, end)
    requirement = summary.get("requirement") or {}
    if summary.get("slew_started") and not requirement.get("met") and not requirement.get("explained"):
        report.add(
            "back_in_control",
            f"the requirement was missed with no fault to explain it: {requirement.get('why')}",
        )


def _unrecoverable(faults: Sequence[InjectedFault], bounds: Bounds, end: float) -> bool:
    """Whether a fault came (by the run's ``end``) that no host could recover from within the outage
    bound."""
    for f in faults:
        if (
            f.t <= end
            and f.kind in ("stall", "unplug", "phone_gap")
            and f.params.get("duration_s", 0.0) >= bounds.recover_within_s - 2.0
        ):
            return True
    return False


def _rearmed_through_handshake(
    report: InvariantReport, record: RunRecorder, rows: Mapping[str, np.ndarray]
) -> None:
    """After each reset the host re-armed through the protocol: no live row shows the board ARMED between
    the reset's report and the host's Arm (``rearm_sent``, or the operator's Arm) — the Arm's send, not its
    answer: a board that took the Arm shows ARMED at once though its Ack may be lost on the way back."""
    t, link, state = rows["t"], rows["board_link"], rows["board_state"]
    for reset in (e for e in record.events if e["kind"] == "board_reset"):
        after = reset["t"]
        rearm = next(
            (
                e["t"]
                for e in record.events
                if e["t"] >= after
                and (e["kind"] == "rearm_sent" or (e["kind"] == "command" and e.get("command") == "arm"))
            ),
            math.inf,
        )
        early = (t > after + 1e-9) & (t < rearm - 1e-9) & (link == BoardLink.LIVE) & (state == 2)
        if early.any():
            k = int(np.argmax(early))
            report.add("back_in_control", f"the board armed at t={t[k]:.3f} s, before the host re-armed it")


def _spun_up_to_steer(
    report: InvariantReport,
    record: RunRecorder,
    rows: Mapping[str, np.ndarray],
    bounds: Bounds,
    faults: Sequence[InjectedFault],
    end: float,
) -> None:
    """When the host steers again after a recovery (``resume``) every rotor is at nominal speed (but a
    rotor whose ESC was made to die by then: the rotor of a dead odd channel, ``channel // 2``)."""
    t, rotors = rows["t"], rows["rotor_speed"]
    nominal = bounds.nominal_rotor
    for e in record.events:
        if e["kind"] != "resume":
            continue
        dead = {
            int(f.params["channel"]) // 2
            for f in faults
            if f.kind == "dead_esc" and f.params["channel"] % 2 == 1 and f.t <= min(e["t"], end)
        }
        k = min(int(np.searchsorted(t, e["t"] - 1e-9)), len(t) - 1)
        speeds = np.delete(rotors[k], sorted(u for u in dead if u < rotors.shape[1]))
        if np.all(np.isnan(speeds)):
            continue
        if np.any(~(np.abs(speeds - nominal) <= 1.5 * SPUN_UP * nominal)):
            report.add(
                "back_in_control",
                f"steering again at t={e['t']:.3f} s with rotors at {np.round(speeds, 1).tolist()} rad/s",
            )


def _short(value: Any) -> str:
    return f"{value:.3g}" if isinstance(value, float) else str(value)
