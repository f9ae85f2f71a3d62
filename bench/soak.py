"""The fault soak: the host (:func:`hil.runtime.run`, as ``hil run`` runs it) against the emulated board
through many cycles of faults, every cycle checked.

Faults, each cycle one fault and the host's recovery from it:

============  ==========  ===========================================================================
kind          mode        how
============  ==========  ===========================================================================
stall         lockstep    the link carries nothing for 0.6 s (``emu://?stall=AT:0.6``): the board fails
                          safe; the host sees its telemetry go stale, then the FAILSAFE
hang          lockstep    the MCU's main loop hangs (``hang_at``): the MCU watchdog resets the board
brownout      lockstep    the pack collapses for 0.3 s (``brownout_at``): a brown-out reset
corruption    lockstep    1 % of the bytes damaged, both ways, all run long (``corrupt=0.01``); a cycle
                          is a stretch of the run as long as the others'
phone_gap     lockstep    the world's phone stops for 1 s (``phone_gap``) and streams again
kill          pty         ``firmware-sim --world`` killed with SIGKILL and started again 0.5-6 s later
phone_pause   pty         the phone's UDP stream paused for 1 s by the relay between phone and host
hostile       pty         hostile datagrams to the host's phone port
                          (:func:`bench.soak_phone.hostile_datagrams`)
second_host   pty         another host opens the board's port: refused (it is locked), naming the
                          holder; the run notices nothing
kill          can         ``firmware-sim --world --can`` on a ``udp_multicast`` bus (classic CAN, then
                          CAN FD: modes ``can``, ``can-fd``), killed and started again as on a pty
freeze        can         the board's process stopped (SIGSTOP) for 0.6 s and let go: the board fails
                          safe; the host sees its telemetry go stale, then the FAILSAFE
noise         can         a noisy node on the bus for 1 s: 200 damaged segments a second under the
                          board's and the host's arbitration ids; counted, every outage recovered
phone_pause   can         as on a pty
============  ==========  ===========================================================================

**Every moment, not a chosen one.** Each lockstep cycle is a run of its own (the in-process board on the
host's clock: fault times exact, the board's own outputs inspectable) given its fault at a moment drawn
uniformly over the whole run — the handshake, the still window, the spin-up, the slew, the hold
(:func:`draw_times`, reproducible from ``--seed``) — and checked with the fault campaigns' invariants
(:mod:`hil.runtime.invariants`) besides the checks below. The pty run is one ``hil run --port`` against
firmware-sim with its world on a pty, in real time, the host in a thread of this process (its run observer
timestamps everything): its first fault comes at a moment drawn from the run's start (the handshake and
the first warm-up included: a board restarted then never came back, issue 25), each next one at a drawn
delay after the host has the board back (its recovery warm-up, the still window, the resumed slew).

After each fault it checks (a failed check is a *problem* of the cycle; a cycle without one survived):

- no crash or hang: the run goes on (and ends by itself, or when told, within its time);
- the fault detected and reported with its cause within its bound (:data:`DETECT_S`; a reset's cause
  within :data:`RESET_S`);
- the board fails safe within its link timeout + one pulse frame (stall cycles: the board's own pulse
  record, from the last frame it took to the first frame with every rotor at the safe pulse);
- re-arming only through the handshake: after a reset the host's ``rearmed`` follows the new handshake's
  reset report, and no live row shows the board armed before it;
- no stale row: a row without a live board has no board value; a live row's telemetry is younger than the
  stale bound (checked on every row of the run as it is written);
- the host back in control (``board_back`` / ``phone_back``) within :data:`BACK_S`, and steering again
  (``resume``) after a recovery;
- nothing logged lost: ``telemetry.csv`` holds every row the run wrote (one per control tick in lockstep),
  ``events.jsonl`` every event, no fault record dropped; the phone receiver counted every datagram.

Figures: cycles survived, detection latency (fault → its first report), time back in control and time to
steering again, p50 / p99, per kind and overall. Next to the detection latency, the board client's own
silence detector (its ``SilenceEvent``, 1 s) on the same faults, where it fires.

    python -m bench.soak --ci --json soak.json      # the short soak CI runs (tests/test_soak.py)
    python -m bench.soak --cycles 40 --pty 5        # per kind
    python -m bench.soak --cycles 0 --pty 0 --can 3 # on CAN only
    python -m bench soak                            # the benchmark (bench/bench_soak.py): >= 200 cycles
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
import zlib
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from hil.runtime import RunOptions, run
from hil.runtime.faults import BoardLink
from hil.runtime.observer import RunAborted, RunStart
from hil.runtime.runlog import read_events, read_telemetry
from hil.runtime.telemetry import board_columns
from hil.scenario import load_scenario

SCENARIO = "cubesat-1u"
LOCKSTEP_KINDS = ("stall", "hang", "brownout", "corruption", "phone_gap")
PTY_KINDS = ("kill", "phone_pause", "hostile", "second_host")
CAN_KINDS = ("kill", "freeze", "noise", "phone_pause")
"""What the soak does to the Python board with its world on a ``udp_multicast`` CAN bus, classic CAN and
CAN FD, in real time: the pty's board faults (a bus has no port to lock: no ``second_host``) plus a frozen
board and a noisy node (a bus's corruption)."""
AVR_KINDS = ("kill", "kill_harness", "second_host")
"""What the soak does to the firmware under simavr (``firmware-sim --avr``, no world: its units are the
firmware's own estimates and the phone a still stand-in), in real time over a pty."""
STALL_S, GAP_S, PAUSE_S = 0.6, 1.0, 1.0
FREEZE_S = 0.6  # a board process stopped (SIGSTOP) this long, then let go (SIGCONT): a real-time stall
NOISE_S, NOISE_HZ = 1.0, 200.0  # a noisy node on a bus: this long, this many damaged segments a second
RESTART_S = (0.5, 6.0)  # a killed board is started again after a delay drawn from this range (s)
STALE_S = 0.25  # the host's stale bound (hil.runtime.faults.STALE_AFTER_S)
BUS_MODES = ("can", "can-fd")
REAL_TIME = ("pty", "avr", *BUS_MODES)  # the real-time modes: a pty, the firmware, a bus
DETECT_S = {"lockstep": STALE_S + 0.045} | dict.fromkeys(REAL_TIME, STALE_S + 0.25)  # + ticks; + slack
RESET_S = 1.5  # fault → the reset's cause reported (MCU watchdog 0.5 s, brown-out 0.3 s, boot, handshake)
BACK_S = {"lockstep": 4.0} | dict.fromkeys(REAL_TIME, 12.0)  # fault → in control again (restart, back-off)
STEER_S = {"lockstep": 6.5} | dict.fromkeys(REAL_TIME, 16.0)  # fault → steering again (spin-up, still)
FAILSAFE_S = 0.25 + 1 / 50.0  # link timeout + one pulse frame (cubesat-1u: 50 Hz frames)
RECOVER_WITHIN_S = 15.0


@dataclass
class Cycle:
    """One fault and what the host made of it; times in s from the fault (None: not applicable)."""

    kind: str
    mode: str
    t_fault: float  # host clock
    detection_s: float | None = None
    silence_s: float | None = None  # the board client's SilenceEvent, the peer
    back_s: float | None = None
    steering_s: float | None = None
    failsafe_s: float | None = None
    cause: str = ""
    problems: list[str] = field(default_factory=list)

    @property
    def survived(self) -> bool:
        return not self.problems


class Recorder:
    """The run's observer (:mod:`hil.runtime.observer`): keeps every event and a compact record of every
    row (time, link, board state, phase), checks each row for staleness as it is written, maps the host's
    clock to ``time.monotonic`` and calls ``on_tick`` (fault probes) on the control thread."""

    def __init__(self, n_units: int) -> None:
        self.columns = board_columns(n_units)
        self.events: list[dict[str, Any]] = []
        self.rows: list[tuple[float, int, float, int]] = []  # t, board_link, board_state (NaN), phase
        self.stale_rows: list[tuple[float, str]] = []
        self.start: RunStart | None = None
        self.offset: float | None = None  # time.monotonic() - host t
        self.on_tick: Any = None
        self.abort: str | None = None
        self.summary: dict[str, Any] = {}

    def started(self, start: RunStart) -> None:
        self.start = start

    def row(self, row: Any) -> None:
        t, link, state = row["t"], row["board_link"], row["board_state"]
        if link != BoardLink.LIVE:
            full = [c for c in self.columns if row[c] is not None]
            if full:
                self.stale_rows.append((t, f"board_link {link} with board values in {full[:3]}"))
        elif row["tel_age_ms"] is None or row["tel_age_ms"] > STALE_S * 1e3 + 1e-6:
            self.stale_rows.append((t, f"live with telemetry {row['tel_age_ms']} ms old"))
        self.rows.append((t, int(link), np.nan if state is None else float(state), int(row["phase"])))

    def event(self, record: Any) -> None:
        self.events.append(dict(record))

    def tick(self, t: float) -> None:
        self.offset = time.monotonic() - t
        if self.on_tick is not None:
            self.on_tick(t)
        if self.abort is not None:
            raise RunAborted(self.abort)

    def finished(self, summary: Any) -> None:
        self.summary = dict(summary)

    def now(self) -> float:
        """The host's clock now (real time)."""
        assert self.offset is not None
        return time.monotonic() - self.offset

    def steering(self, after: float, before: float = np.inf) -> dict[str, Any] | None:
        """The first record of the host steering after ``after``: a ``resume`` (a recovery's slew), or a
        ``slew_start`` when the fault came before the run's first slew (its warm-up started again)."""
        found = [
            e for e in (self.first("resume", after, before), self.first("slew_start", after, before)) if e
        ]
        return min(found, key=lambda e: e["t"], default=None)

    def first(self, kind: str, after: float, before: float = np.inf, **match: Any) -> dict[str, Any] | None:
        for e in self.events:
            if (
                e["kind"] == kind
                and after <= e["t"] < before
                and all(e.get(k) == v for k, v in match.items())
            ):
                return e
        return None


# =========================================================================== checks shared by both modes
def check_recovery(c: Cycle, rec: Recorder, end: float, mode: str, faults: list[dict[str, Any]]) -> None:
    """Detection (the first of the cycle's own fault records) with its cause, back in control, steering
    again, re-arming through the handshake, no stale row; into ``c``."""
    t0 = c.t_fault
    mine = [f for f in faults if t0 <= f["t"] < end]
    want = {
        "stall": "stale",
        "hang": "stale",
        "brownout": "stale",
        "kill": "link_lost",
        "kill_harness": "link_lost",
        "freeze": "stale",
        "phone_gap": "phone_gap",
        "phone_pause": "phone_gap",
    }[c.kind]
    if c.kind == "kill" and mode in BUS_MODES:
        want = "stale"  # a bus has no connection to lose: the board falls silent, then reports its reset
    first = next((f for f in mine if f["kind"] == want), None)
    if first is None:
        c.problems.append(f"no {want} reported")
        return
    c.detection_s = first["t"] - t0
    if c.detection_s > DETECT_S[mode]:
        c.problems.append(f"{want} reported {c.detection_s:.3f} s after the fault (bound {DETECT_S[mode]} s)")
    silence = rec.first("silence", t0, end, ended=False)
    c.silence_s = None if silence is None else silence["t"] - t0
    causes = {"stall": ("failsafe", None), "freeze": ("failsafe", None),
              "hang": ("reset", "WATCHDOG"), "brownout": ("reset", "BROWN_OUT"),
              "kill_harness": ("reset", "POWER_ON"),
              "kill": ("reset", "POWER_ON")}  # fmt: skip
    if c.kind in causes:
        kind, cause = causes[c.kind]
        found = next((f for f in mine if f["kind"] == kind and f.get("cause") == cause), None)
        if found is None:
            c.problems.append(f"no {kind} {cause or ''} reported".rstrip())
        else:
            c.cause = f"{kind} {cause}" if cause else kind
            if kind == "reset" and mode == "lockstep" and found["t"] - t0 > RESET_S:
                c.problems.append(
                    f"reset reported {found['t'] - t0:.2f} s after the fault (bound {RESET_S} s)"
                )
            _rearmed_through_handshake(c, rec, found["t"], end)
    else:
        c.cause = want
    back = rec.first("phone_back" if "phone" in c.kind else "board_back", first["t"], end)
    if back is None:
        c.problems.append("never back in control")
        return
    c.back_s = back["t"] - t0
    if c.back_s > BACK_S[mode]:
        c.problems.append(f"back in control {c.back_s:.2f} s after the fault (bound {BACK_S[mode]} s)")
    resume = rec.steering(back["t"] - 1e-9, end)
    if resume is None:
        c.problems.append("never steering again")
    else:
        c.steering_s = resume["t"] - t0
        if c.steering_s > STEER_S[mode]:
            c.problems.append(
                f"steering again {c.steering_s:.2f} s after the fault (bound {STEER_S[mode]} s)"
            )
    stale = [why for t, why in rec.stale_rows if t0 <= t < end]
    if stale:
        c.problems.append(f"{len(stale)} stale rows: {stale[0]}")


def _rearmed_through_handshake(c: Cycle, rec: Recorder, reported: float, end: float) -> None:
    """After a reset (reported when the new handshake answered) or a failsafe, the host's re-arm comes
    after the report, and no live row shows the board ARMED between the fault and the re-arm."""
    rearmed = rec.first("rearmed", reported - 1e-9, end)
    sent = rec.first("rearm_sent", reported - 1e-9, end)
    if rearmed is None or sent is None:
        c.problems.append("not re-armed after the reset/failsafe")
        return
    armed_early = [
        t for t, link, state, _ in rec.rows if reported < t < sent["t"] - 1e-9 and link == 0 and state == 2
    ]
    if armed_early:
        c.problems.append(f"the board armed at t={armed_early[0]:.3f} s before the host re-armed it")


def check_logs(run_dir: Path, rec: Recorder, summary: dict[str, Any], lockstep: bool) -> list[str]:
    """Nothing logged lost: every row and event the run wrote is in its files, in order."""
    problems = []
    tel = read_telemetry(run_dir / "telemetry.csv")
    events, bad = read_events(run_dir / "events.jsonl")
    if tel.dropped_lines or tel.rows != len(rec.rows):
        problems.append(
            f"telemetry.csv has {tel.rows} rows ({tel.dropped_lines} bad), the run wrote {len(rec.rows)}"
        )
    elif not np.array_equal(tel["t"], np.array([r[0] for r in rec.rows])):
        problems.append("telemetry.csv's times are not the rows' times")
    if bad or len(events) != len(rec.events):
        problems.append(
            f"events.jsonl has {len(events)} records ({bad} bad), the run wrote {len(rec.events)}"
        )
    if lockstep and tel.rows != summary.get("control_ticks"):
        problems.append(f"{tel.rows} rows for {summary.get('control_ticks')} control ticks")
    if summary.get("faults_not_kept"):
        problems.append(f"{summary['faults_not_kept']} fault records not kept")
    return problems


# =========================================================================== lockstep
LOCKSTEP_DURATION_S = 22.0  # each lockstep cycle's run, from its slew's start
_AS_INJECTED = {"stall": "stall", "hang": "hang", "brownout": "brownout", "corruption": "noise",
                "phone_gap": "phone_gap"}  # fmt: skip
_PARAMS = {"stall": {"duration_s": STALL_S}, "phone_gap": {"duration_s": GAP_S},
           "corruption": {"duration_s": 3.0, "corrupt": 0.01}}  # fmt: skip


def draw_times(kind: str, cycles: int, window_s: float, seed: int) -> list[float]:
    """``cycles`` fault moments for ``kind``, uniform over a run's whole span ``[0, window_s)`` (s from
    the run's start: handshake, warm-up, spin-up, slew, hold), reproducible from ``seed``."""
    rng = np.random.default_rng([seed, zlib.crc32(kind.encode())])
    return [float(t) for t in rng.uniform(0.0, window_s, cycles)]


def lockstep_kind(kind: str, cycles: int, out_root: Path, seed: int = 0) -> list[Cycle]:
    """``cycles`` lockstep runs, each given one fault of ``kind`` at a moment drawn over the whole run
    (:func:`draw_times`); each run checked with the campaigns' invariants
    (:func:`hil.runtime.invariants.check_run`: detection, no stale row, safe pulses, an honest exit, back
    in control) and the soak's own checks (the board's failsafe timing, nothing logged lost)."""
    from hil.montecarlo.fault_plan import fault_options, run_window_s
    from hil.montecarlo.runner import fault_bounds
    from hil.runtime.invariants import InjectedFault, check_run
    from hil.runtime.observer import Observers
    from hil.runtime.record import RunRecorder

    base = load_scenario(SCENARIO)
    base = base.with_changes(slew=replace(base.slew, duration_s=LOCKSTEP_DURATION_S))
    out: list[Cycle] = []
    for i, t in enumerate(draw_times(kind, cycles, run_window_s(base), seed)):
        fault = InjectedFault(_AS_INJECTED[kind], t, dict(_PARAMS.get(kind, {})))
        scenario = base.with_changes(fault_options=fault_options((fault,), {}))
        rec = Recorder(scenario.n_units)
        probe = _FailsafeProbe(rec, [t]) if kind == "stall" else _LinkCounter(rec, [t])
        rec.on_tick = probe
        record = RunRecorder(scenario.n_units)
        c = Cycle(kind, "lockstep", t)
        out.append(c)
        try:
            result = run(scenario, RunOptions(out_root=out_root / f"{i:03d}", observer=Observers(rec, record),
                                              recover_within_s=RECOVER_WITHIN_S))  # fmt: skip
        except Exception as exc:  # a crash: what the soak looks for
            c.problems.append(f"the run failed: {exc!r}")
            continue
        report = check_run([fault], record, fault_bounds(scenario))
        c.problems += [f"{name}: {m}" for name, ms in report.violations.items() for m in ms]
        c.detection_s = min((s for _, s in report.detection), default=None)
        c.back_s = report.recovery[0][1] if report.recovery else None
        resume = rec.steering(t)
        c.steering_s = None if resume is None else resume["t"] - t
        c.cause = ", ".join(sorted({f["kind"] for f in result.summary.get("faults", []) if f["t"] >= t})) or (
            "unseen: " + "; ".join(report.unseen) if report.unseen else "none"
        )
        silence = rec.first("silence", t, ended=False)
        c.silence_s = None if silence is None else silence["t"] - t
        if result.run_dir is not None:
            c.problems += check_logs(result.run_dir, rec, result.summary, lockstep=True)
        if kind == "stall" and _armed_before(rec, t):
            assert isinstance(probe, _FailsafeProbe)
            _check_failsafe(c, probe, 0)
        if kind == "corruption":
            _check_corruption(c, rec, probe, 0, t + 3.0, result.summary.get("faults", []))
    return out


def _armed_before(rec: Recorder, t: float) -> bool:
    """Whether the host's last row before ``t`` saw the board live and ARMED (a stall then must fail it
    safe; one during the handshake or while it is disarmed has nothing to make safe)."""
    before = [r for r in rec.rows if r[0] < t]
    return bool(before) and before[-1][1] == BoardLink.LIVE and before[-1][2] == 2


class _LinkCounter:
    """At each cycle's start and end: the link's bad-frame counters (host's deframer, board's receiver)."""

    def __init__(self, rec: Recorder, times: list[float]) -> None:
        self.rec, self.times = rec, times
        self.at: dict[int, int] = {}

    def __call__(self, t: float) -> None:
        start = self.rec.start
        for i, t0 in enumerate(self.times):
            if i not in self.at and t >= t0 and start is not None:
                stats = start.host.client.stats()
                self.at[i] = sum(stats.bad_frames.values()) + (stats.board_rx_bad or 0)


class _FailsafeProbe(_LinkCounter):
    """Stall cycles: the last frame the board took before each stall (its receiver's clock, read during
    the stall), for the failsafe check against the board's pulse record."""

    def __init__(self, rec: Recorder, times: list[float]) -> None:
        super().__init__(rec, times)
        self.last_rx: dict[int, float] = {}
        self.safe_at: dict[int, float | None] = {}

    def __call__(self, t: float) -> None:
        super().__call__(t)
        start = self.rec.start
        if start is None:
            return
        board = start.host.client.transport.board  # type: ignore[attr-defined]  # emu://: the board itself
        for i, t0 in enumerate(self.times):
            if i not in self.last_rx and t0 + 0.1 <= t < t0 + STALL_S:
                self.last_rx[i] = board.commands.last_rx_us / 1e6
            if i in self.last_rx and i not in self.safe_at and t >= t0 + STALL_S:
                safe = board.config.rotor_safe_us
                self.safe_at[i] = next(
                    (f.t for f in board.timeline.frames
                     if f.t > self.last_rx[i] and all(w == safe for w in f.widths[1::2])), None,
                )  # fmt: skip


def _check_failsafe(c: Cycle, probe: _FailsafeProbe, i: int) -> None:
    safe, last = probe.safe_at.get(i), probe.last_rx.get(i)
    if safe is None or last is None:
        c.problems.append("the board's rotors never went to the safe pulse")
        return
    c.failsafe_s = safe - last
    if c.failsafe_s > FAILSAFE_S + 1e-6:
        c.problems.append(
            f"failsafe {c.failsafe_s * 1e3:.1f} ms after the last frame (bound {FAILSAFE_S * 1e3:.0f} ms)"
        )


def _check_corruption(c: Cycle, rec: Recorder, counter: _LinkCounter, i: int, end: float,
                      faults: list[dict[str, Any]]) -> None:  # fmt: skip
    """A stretch of a run with 1 % of the bytes damaged: damaged frames counted (the fault detected),
    every outage in it over within the bound, no stale row."""
    before, after = counter.at.get(i), counter.at.get(i + 1)
    if before is not None and after is not None and after <= before:
        c.problems.append("no damaged frame counted")
    c.cause = "crc"  # a continuous fault: no detection latency of its own
    check_outages(c, rec, end, faults)


def check_outages(c: Cycle, rec: Recorder, end: float, faults: list[dict[str, Any]]) -> None:
    """A damaging fault from ``c.t_fault`` to ``end`` (corrupted bytes, a noisy bus): every outage it
    caused (stale, failsafe, reset) over — the host back in control — within :data:`RECOVER_WITHIN_S`,
    and no stale row; the outages are counted into ``c.cause``."""
    t0 = c.t_fault
    episodes = [f for f in faults if t0 <= f["t"] < end and f["kind"] in ("stale", "failsafe", "reset")]
    c.cause = f"{c.cause}, {len(episodes)} outage faults"
    for f in episodes:
        if rec.first("board_back", f["t"], end + RECOVER_WITHIN_S) is None:
            c.problems.append(f"{f['kind']} at t={f['t']:.2f} s: never back in control")
            break
    stale = [why for t, why in rec.stale_rows if t0 <= t < end]
    if stale:
        c.problems.append(f"{len(stale)} stale rows: {stale[0]}")


# =========================================================================== summary
def figures(cycles: list[Cycle]) -> dict[str, Any]:
    """Cycles survived, and p50 / p99 of detection, back-in-control and steering-again times, overall and
    per kind (s)."""

    def pct(values: list[float]) -> dict[str, float | None]:
        if not values:
            return {"p50": None, "p99": None, "max": None, "n": 0}
        a = np.asarray(values)
        return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
                "max": float(a.max()), "n": int(a.size)}  # fmt: skip

    def of(group: list[Cycle]) -> dict[str, Any]:
        return {
            "cycles": len(group),
            "survived": sum(c.survived for c in group),
            "detection_s": pct([c.detection_s for c in group if c.detection_s is not None]),
            "silence_s": pct([c.silence_s for c in group if c.silence_s is not None]),
            "back_s": pct([c.back_s for c in group if c.back_s is not None]),
            "steering_s": pct([c.steering_s for c in group if c.steering_s is not None]),
            "failsafe_s": pct([c.failsafe_s for c in group if c.failsafe_s is not None]),
        }

    order = list(dict.fromkeys(LOCKSTEP_KINDS + PTY_KINDS + CAN_KINDS + AVR_KINDS))
    kinds = sorted({c.kind for c in cycles}, key=order.index)
    return {"all": of(cycles), **{k: of([c for c in cycles if c.kind == k]) for k in kinds}}


def soak(
    cycles: int,
    pty: int,
    out_root: Path,
    kinds: tuple[str, ...] = LOCKSTEP_KINDS + PTY_KINDS + CAN_KINDS + AVR_KINDS,
    seed: int = 0,
    avr: int = 0,
    can: int = 0,
) -> list[Cycle]:
    """``cycles`` of each lockstep kind, ``pty`` of each pty kind against the Python board, ``can`` of each
    bus kind against it on classic CAN and on CAN FD, and ``avr`` of each against the firmware on simavr,
    the moments drawn from ``seed``."""
    from bench.soak_pty import pty_soak

    out: list[Cycle] = []
    for kind in kinds:
        if kind in LOCKSTEP_KINDS and cycles:
            out += lockstep_kind(kind, cycles, out_root / kind, seed)
    plan = [k for _ in range(pty) for k in PTY_KINDS if k in kinds]
    if plan:
        out += pty_soak(plan, out_root / "pty", seed)
    can_plan = [k for _ in range(can) for k in CAN_KINDS if k in kinds]
    if can_plan:
        for bus in ("can", "can-fd"):
            out += pty_soak(can_plan, out_root / bus, seed, target=bus)
    avr_plan = [k for _ in range(avr) for k in AVR_KINDS if k in kinds]
    if avr_plan:
        out += pty_soak(avr_plan, out_root / "avr", seed, target="avr")
    return out


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.ERROR, format="%(levelname)s %(name)s: %(message)s")
    p = argparse.ArgumentParser(prog="python -m bench.soak", description=__doc__.split("\n\n")[0])
    p.add_argument("--ci", action="store_true", help="the short soak: 2 cycles of each kind")
    p.add_argument("--cycles", type=int, default=40, help="cycles of each lockstep kind (default 40)")
    p.add_argument("--pty", type=int, default=5, help="cycles of each pty kind (default 5)")
    p.add_argument(
        "--avr", type=int, default=0, help="cycles of each kind against the firmware on simavr (default 0)"
    )
    p.add_argument(
        "--can",
        type=int,
        default=0,
        help="cycles of each bus kind on udp_multicast, classic CAN and CAN FD (default 0)",
    )
    every = tuple(dict.fromkeys(LOCKSTEP_KINDS + PTY_KINDS + CAN_KINDS + AVR_KINDS))
    p.add_argument("--kinds", nargs="+", choices=every, default=every)
    p.add_argument("--json", type=Path, help="write every cycle and the figures here")
    p.add_argument("--keep", type=Path, help="keep the run directories here (default: a temporary one)")
    p.add_argument("--seed", type=int, default=0, help="draws the faults' moments (default 0)")
    args = p.parse_args(argv)
    cycles, pty, avr = (2, 2, args.avr and 1) if args.ci else (args.cycles, args.pty, args.avr)
    can = (args.can and 1) if args.ci else args.can
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="soak-") as tmp:
        root = args.keep or Path(tmp)
        result = soak(cycles, pty, root, tuple(args.kinds), args.seed, avr, can)
    wall = time.monotonic() - started
    figs = figures(result)
    for c in result:
        if not c.survived:
            print(
                f"FAILED {c.kind} ({c.mode}) at t={c.t_fault:.2f} s: {'; '.join(c.problems)}", file=sys.stderr
            )
    for name, f in figs.items():
        det, back, steer = f["detection_s"], f["back_s"], f["steering_s"]
        print(f"{name:<12} {f['survived']:4d}/{f['cycles']:<4d} survived  detection p50 {_ms(det['p50'])} "
              f"p99 {_ms(det['p99'])}  back p50 {_s(back['p50'])} p99 {_s(back['p99'])}  "
              f"steering p50 {_s(steer['p50'])} p99 {_s(steer['p99'])}")  # fmt: skip
    print(f"{len(result)} cycles in {wall:.1f} s")
    if args.json:
        args.json.write_text(json.dumps({"cycles": [asdict(c) | {"survived": c.survived} for c in result],
                                         "figures": figs, "wall_s": wall}, indent=1))  # fmt: skip
    return 0 if all(c.survived for c in result) else 1


def _ms(v: float | None) -> str:
    return "    -   " if v is None else f"{v * 1e3:6.0f} ms"


def _s(v: float | None) -> str:
    return "   -   " if v is None else f"{v:5.2f} s"


if __name__ == "__main__":
    sys.exit(main())
