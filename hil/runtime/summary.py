"""The run's summary (``summary.json``'s host part): its counts, its pointing figures, the faults and the
outages they made, the operator's commands, and whether the run met its pointing requirement — and when
it did not, why, from what the record holds."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from hil.link.board import BoardClient
from hil.runtime.faults import FaultJournal
from hil.runtime.phases import RunPhases
from hil.runtime.telemetry import RunTrace
from hil.runtime.watch import BoardWatch
from hil.scenario import Scenario
from protocol.errors import HilError


@dataclass
class HostCounters:
    """What the host has done so far: estimator steps, phone samples fed (accepted or not), control
    ticks, setpoints the board reset under, phone clock re-anchorings; the control ticks on which steering
    had no finite command to give (``unsteered_ticks``: :attr:`hil.control.steering.Saturation.NOT_FINITE`,
    a NaN estimate, say — the array was given none) and the episodes of them (``unsteered_episodes``: runs
    of such ticks, each logged once as an ``unsteered`` event)."""

    estimator_steps: int = 0
    samples: int = 0
    control_ticks: int = 0
    setpoint_errors: int = 0
    phone_restarts: int = 0
    unsteered_ticks: int = 0
    unsteered_episodes: int = 0


def run_summary(
    *,
    now: float,
    scenario: Scenario,
    client: BoardClient,
    watch: BoardWatch,
    journal: FaultJournal,
    phases: RunPhases,
    counters: HostCounters,
    trace: RunTrace,
    estimator_rmse: float | None,
    phone_admission: dict[str, Any],
    operator_log: list[dict[str, Any]],
    lost: str | None,
    phone_merge: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The run's figures: settle time (first time after which the pointing error stays ≤ settle_deg,
    from the slew's start), final and peak pointing error, peak gimbal rate, minimum δ, the
    estimator's RMSE over slew + hold (``estimator_rmse``, simulated runs); the faults — failsafes,
    resets, link losses, reconnects, stale telemetry, phone gaps, each with its time and cause — and the
    outages they made (:meth:`hil.runtime.faults.FaultJournal.summary`); ``board``: who answered the
    last handshake (its HelloReply: identity, serial, firmware build, units, frame rate); the operator's
    commands and suspensions; ``lost`` why the run lost the board (or the phone), if it did; None where
    not reached; ``phone_admission`` the admission's counts, ``phone_merge`` the merger's (per sensor:
    accepted, dropped by reason, stale steps). Taken at ``now`` (host s): the run's end."""
    since = phases.suspended_since
    gimbal_rate_limit = scenario.spacecraft.limits.max_gimbal_rate
    info = client.session.info
    out: dict[str, Any] = {
        "scenario": scenario.name,
        "board": None if info is None else info.describe(),
        "settle_requirement_deg": scenario.settle_deg,
        "slew_started": phases.slew_start is not None,
        "failsafe_events": watch.failsafes,
        "board_resets": watch.resets,
        "link_lost": watch.link_losses,
        "reconnects": watch.reconnects,
        "rearms": watch.rearms,
        "stale_episodes": watch.stale_episodes,
        "host_stalls": watch.host_stalls,
        "board_logs_unrecorded": watch.board_logs_unrecorded,
        "phone_gaps": len(journal.phone_gaps),
        "phone_restarts": counters.phone_restarts,
        "unsteered_ticks": counters.unsteered_ticks,
        "unsteered_episodes": counters.unsteered_episodes,
        "unsteered_s": counters.unsteered_ticks / scenario.loop.control_rate_hz,
        "lost": lost or journal.open_at_end(now) or journal.lost_after_the_run(),
        "estimator_steps": counters.estimator_steps,
        "phone_samples": counters.samples,
        "control_ticks": counters.control_ticks,
        "max_gimbal_rate_limit": gimbal_rate_limit,
        "operator": [dict(entry) for entry in operator_log],
        "operator_commands": len(operator_log),
        "suspended_s": phases.suspended_s + (0.0 if since is None else now - since),
        # ... of it after the slew's start: what moves the run's end (RunPhases.time_is_up)
        "suspended_after_slew_s": phases.suspended_after_slew_s
        + (0.0 if since is None or phases.slew_start is None else now - max(since, phases.slew_start)),
        "suspended_at_end": since,
    }
    slew, slew_start = phases.slew, phases.slew_start
    # the trace's time runs from the first slew's start; a retarget's or a recovery's slew starts later
    slew_end_s = None if slew is None or slew_start is None else slew.start_s + slew.duration_s - slew_start
    out.update(trace.figures(scenario.settle_deg, gimbal_rate_limit, slew_end_s))
    if len(trace):
        out["slew_s"] = None if phases.slew is None else phases.slew.duration_s
    out["estimator_rmse_deg"] = estimator_rmse
    out["phone_admission"] = phone_admission
    # what the merger dropped of what the admission accepted (a NaN the admission let through, none
    # should be): beside the admission's counts, so no reading the host took is lost without a count
    out["phone_merge"] = phone_merge
    out["requirement"] = requirement(out, now, phases, journal, operator_log, client)
    faults = journal.summary(now)
    out["phone_gap_list"] = faults.pop("phone_gaps")
    out.update(faults)
    return out


RAN_OUT_UNARMED = "incomplete: the run's time ran out with the board"
"""The start of the exit reason of a run whose time ran out with the board not in hand and ARMED
(``completed`` says it was; :func:`hil.runtime.loop._outcome`)."""
DISARM_UNCONFIRMED = "incomplete: the run completed, but the board is not confirmed disarmed"
"""The start of the exit reason of a run that completed but whose final Disarm failed
(:class:`hil.runtime.loop.FinalDisarm`)."""


CHANGES_NOTHING = ("readings_dropped",)
"""Journal records of faults the host rides through unchanged: hostile phone readings, dropped and counted
(docs/faults.md) — nothing else changes, so they never explain a missed requirement (before, one spoof
during the slew made a controller that did not settle pass for one a fault had held back)."""


def requirement(
    figures: dict[str, Any],
    now: float,
    phases: RunPhases,
    journal: FaultJournal,
    operator_log: list[dict[str, Any]],
    client: BoardClient,
) -> dict[str, Any]:
    """Whether the run met its pointing requirement (settled within ``settle_deg``: ``figures``' ``settled``)
    and, when it did not, why — what the record holds that explains it: the operator's suspensions and
    retargets, the control ticks steering had no finite command for, the faults since the slew started (but
    those that change nothing: :data:`CHANGES_NOTHING`),
    frames damaged on the link, a recovery that left too little time (at ``now``, host s). ``explained``
    is False when nothing in the record explains a miss (a controller that did not settle on its own)."""
    if figures.get("settled"):
        return {"met": True, "why": None, "explained": True}
    reasons: list[str] = []
    if phases.slew_start is None:
        reasons.append("the slew never started")
    suspended = figures.get("suspended_s") or 0.0
    if suspended > 0 or phases.suspended_since is not None:
        reasons.append(f"disarmed by the operator for {suspended:.1f} s")
    unsteered = figures.get("unsteered_ticks") or 0
    if unsteered:
        reasons.append(
            f"steering had no finite command for {unsteered} control ticks "
            f"({figures.get('unsteered_s', 0.0):.1f} s, {figures.get('unsteered_episodes', 0)} episodes)"
        )
    retargets = [o for o in operator_log if o["command"] in ("slew", "hold") and o["status"] == "applied"]
    if retargets:
        reasons.append(f"retargeted by the operator at t={retargets[-1]['t']:.1f} s")
    since = -math.inf if phases.slew_start is None else phases.slew_start
    kinds: dict[str, int] = {}
    for f in journal.faults:
        if f["t"] >= since and f["kind"] not in CHANGES_NOTHING:
            kinds[f["kind"]] = kinds.get(f["kind"], 0) + 1
    if kinds:
        reasons.append("faults: " + ", ".join(f"{k} x{n}" for k, n in kinds.items()))
    damaged = damaged_frames(client)
    if damaged:
        reasons.append(f"link: {damaged} damaged frames (setpoints and telemetry lost with them)")
    slew = phases.slew
    if slew is not None and phases.slew_start is not None:
        left = now - slew.start_s
        if left < slew.duration_s:
            reasons.append(
                f"steering from t={slew.start_s:.1f} s, {left:.1f} s before the end: its slew "
                f"needed {slew.duration_s:.1f} s"
            )
    explained = bool(reasons)
    if not reasons:
        reasons.append("nothing in the record explains it: the controller did not settle")
    return {"met": False, "why": "; ".join(reasons), "explained": explained}


def damaged_frames(client: BoardClient) -> int:
    """Frames damaged on the link, either way (the host's deframer and the board's receiver); 0 when the
    client has no statistics to give (no session)."""
    try:
        stats = client.stats()
    except HilError:
        return 0
    return sum(stats.bad_frames.values()) + (stats.board_rx_bad or 0)
