"""The uplink: commands from the page, checked by the server, carried out on the host's control tick.

Commands (``POST /api/command``, a JSON object; docs/gcs.md, "Uplink"): ``{"command": "arm"}``,
``"disarm"``, ``"abort"``, ``"hold"``, ``{"command": "slew", "roll_deg": r, "pitch_deg": p, "yaw_deg": y}``
— what each does is :mod:`hil.runtime.operator`'s, which carries them out (the same path a fault
campaign's drawn operator commands take).

The server thread only parses and queues (:meth:`Uplink.submit`, bounded: a full inbox answers 503); the
control thread drains the inbox at the start of each tick (:meth:`Uplink.service`), so a command never
races the control law. Commands are taken only while a run can carry them out: from the run's start
(:meth:`Uplink.open`, when the run's host exists) to its loop's end (:meth:`Uplink.close`); before and
after, a request is refused (409, :class:`UplinkRefused`) — never answered 202 for a command that nothing
will carry out or log (a run that failed to start, its board never opened, lost them all). Every step
is an ``events.jsonl`` record ``{"kind": "command", "origin": "gcs", ...}`` (:mod:`hil.runtime.operator`);
the page shows them against the id the POST returned. Requests the server turns away (wrong token,
foreign origin, a malformed body) are logged the same way with ``status: "rejected"``.
"""

from __future__ import annotations

import json
import re
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hil.numbers import finite_number
from hil.runtime.operator import COMMANDS, TARGET_RANGE_DEG, Operator, OperatorCommand
from protocol.errors import HilError, InputFormatError

if TYPE_CHECKING:
    from hil.runtime.host import Host

MAX_BODY = 4096  # bytes of a command request
INBOX = 16  # commands waiting for the next control tick; more answer 503
REJECTED_LOG = 64  # turned-away requests waiting to be logged; more are counted only
ANGLE_RANGE = dict(zip(("roll_deg", "pitch_deg", "yaw_deg"), TARGET_RANGE_DEG, strict=True))  # the run's
MAX_DEPTH = 8  # JSON nesting: a command is one flat object; deeper is refused before the parser sees it
ALARM_KEY = re.compile(r"[a-z0-9_.:-]{1,64}")  # an alarm's key, as the page names it (static/alarms.js)
_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"')
_BRACKET = re.compile(rb"[\[\]{}]")
_WHERE = "POST /api/command"


def parse_command(body: bytes, command_id: int, remote: str = "") -> OperatorCommand:
    """A request body as an :class:`OperatorCommand` from the ground station; :class:`InputFormatError`
    saying what is wrong otherwise — whatever the bytes, nothing else is raised. The body must be one JSON
    object of at most :data:`MAX_BODY` bytes, nested at most :data:`MAX_DEPTH` deep (checked before
    ``json.loads``, whose recursion ``[`` x 4000 would exhaust), with no key given twice (which of two
    values would count is a guess: ``{"command": "hold", "command": "disarm"}`` is refused, not a disarm)."""
    where = _WHERE
    doc = _json_object(body, where, "a command")
    name = doc.get("command")
    if name not in COMMANDS:
        raise InputFormatError(f"command must be one of {', '.join(COMMANDS)}, got {name!r}", where)
    extra = set(doc) - {"command", *(ANGLE_RANGE if name == "slew" else ())}
    if extra:
        raise InputFormatError(f"unknown field(s) for {name}: {', '.join(sorted(extra))}", where)
    if name != "slew":
        return OperatorCommand(command_id, name, origin="gcs", remote=remote)
    angles = []
    for key, limit in ANGLE_RANGE.items():
        given = doc.get(key)
        value = finite_number(given)
        beyond_float = value is None and isinstance(given, int) and not isinstance(given, bool)
        if value is None and not beyond_float:
            raise InputFormatError(f"{key} must be a number of degrees, got {_shown(given)}", where)
        if value is None or abs(value) > limit:  # an integer past a float's range is past any angle's
            raise InputFormatError(f"{key} must lie within ±{limit:g}°, got {_shown(given)}", where)
        angles.append(value)
    return OperatorCommand(command_id, name, (angles[0], angles[1], angles[2]), "gcs", remote)


def parse_ack(body: bytes, remote: str = "") -> dict[str, Any]:
    """An alarm acknowledgement ``{"alarm": KEY, "raised_t": s}`` (``raised_t``: the run time the alarm
    was raised, so the log says which raising was acknowledged); the same checks as a command's body
    (size, nesting, a key given twice); :class:`InputFormatError` saying what is wrong otherwise."""
    where = "POST /api/ack"
    doc = _json_object(body, where, "an acknowledgement")
    extra = set(doc) - {"alarm", "raised_t"}
    if extra:
        raise InputFormatError(f"unknown field(s): {', '.join(sorted(extra))}", where)
    alarm = doc.get("alarm")
    if not isinstance(alarm, str) or not ALARM_KEY.fullmatch(alarm):
        raise InputFormatError(f"alarm must be an alarm's key ([a-z0-9_.:-], 1-64), got {alarm!r}", where)
    raised = doc.get("raised_t")
    raised_t = None if raised is None else finite_number(raised)
    if raised is not None and raised_t is None:
        raise InputFormatError(f"raised_t must be a number of seconds, got {_shown(raised)}", where)
    return {"alarm": alarm, "raised_t": raised_t, "remote": remote}


def _shown(value: Any, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters: the refusal names what came without echoing an integer
    of 4300 digits into the answer and the run's log."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text)} characters)"


def _json_object(body: bytes, where: str, what: str) -> dict[str, Any]:
    """A request body as one JSON object: UTF-8 text (JSON's encoding; ``json.loads`` would also take
    UTF-16, whose bytes hide brackets from the nesting check), at most :data:`MAX_BODY` bytes, nested at most
    :data:`MAX_DEPTH` deep (checked before ``json.loads``, whose recursion ``[`` x 4000 would exhaust), no
    key given twice; :class:`InputFormatError` naming ``where`` otherwise, whatever the bytes."""
    if len(body) > MAX_BODY:
        raise InputFormatError(f"body of {len(body)} bytes (at most {MAX_BODY})", where)
    try:
        text = body.decode("utf-8-sig")  # a BOM, as json.loads of bytes allows
    except UnicodeDecodeError as exc:
        raise InputFormatError(f"not UTF-8 text ({exc.reason} at byte {exc.start})", where) from None
    depth = _depth(body)
    if depth > MAX_DEPTH:
        raise InputFormatError(f"nested {depth} deep (at most {MAX_DEPTH}): not {what}", where)
    try:
        doc = json.loads(text, object_pairs_hook=_unique_keys)
    except InputFormatError:  # a key given twice (_unique_keys)
        raise
    except ValueError as exc:  # JSONDecodeError, an integer past the digit limit
        raise InputFormatError(f"not JSON: {str(exc)[:200]}", where) from None
    except RecursionError:  # not reachable under MAX_DEPTH; kept so that no input can raise anything else
        raise InputFormatError("not JSON: nested too deep", where) from None
    if not isinstance(doc, dict):
        raise InputFormatError("expected a JSON object", where)
    return doc


def _depth(body: bytes) -> int:
    """How deep the brackets of ``body`` nest, outside JSON strings (an unterminated string's brackets
    count: such a body is refused either way)."""
    depth = deepest = 0
    for bracket in _BRACKET.findall(_STRING.sub(b'""', body)):
        depth += 1 if bracket in (b"[", b"{") else -1
        deepest = max(deepest, depth)
    return deepest


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json.loads``' object hook: an object that gives a key twice is refused."""
    doc: dict[str, Any] = {}
    for key, value in pairs:
        if key in doc:
            raise InputFormatError(f"the key {key[:40]!r} is given twice", _WHERE)
        doc[key] = value
    return doc


@dataclass
class UplinkStats:
    accepted: int = 0
    inbox_full: int = 0
    rejected: int = 0  # requests turned away by the server (token, origin, host, format)
    rejected_unlogged: int = 0  # ... beyond REJECTED_LOG between two ticks
    acks: int = 0  # alarm acknowledgements queued
    no_run: int = 0  # commands and acknowledgements refused because the run had not started (409)
    ended: int = 0  # ... because the run's loop had ended (409): no events.jsonl left to log them in


class UplinkRefused(HilError):
    """A command or an acknowledgement that came when no run can carry it out or log it: the server
    answers 409 with the error and :attr:`reason`."""

    reason = ""


class UplinkNotStarted(UplinkRefused):
    """Before the run has started (its board and phone still being opened; a run that fails to start
    never does): nothing would carry it out, nor log it."""

    reason = "no_run"


class UplinkClosed(UplinkRefused):
    """After the run's last control tick: nothing will carry it out."""

    reason = "ended"


@dataclass
class Uplink:
    """The inbox (server threads) and its executor (the control thread)."""

    stats: UplinkStats = field(default_factory=UplinkStats)

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self._inbox: deque[OperatorCommand] = deque()
        self._rejected: deque[dict[str, Any]] = deque()
        self._acks: deque[dict[str, Any]] = deque()
        self._next_id = 1
        self._opened = False
        self._closed = False
        self.operator = Operator()

    # ------------------------------------------------------------------ the run's start
    def open(self) -> None:
        """The run has started (its host exists, its first control tick is to come: the run observer's
        ``started``): commands and acknowledgements are taken from now on, until :meth:`close`. Another run
        after one that ended (a station kept open for the host's next run) opens it again, with an operator
        of its own (the last run's commands are settled with its board); before, the first run's end
        refused the next run's every command as "the run has ended". Command ids go on counting."""
        with self._lock:
            if self._closed:
                self._closed = False
                self.operator = Operator()
            self._opened = True

    def _refusal(self, what: str) -> UplinkRefused | None:
        """Why ``what`` cannot be taken now (no run yet, or the run has ended), or None. Under the lock."""
        if self._closed:
            self.stats.ended += 1  # counted: the run's events are closed, nothing can log it
            return UplinkClosed(f"the run has ended: no {what} is taken any more")
        if not self._opened:
            self.stats.no_run += 1
            return UplinkNotStarted(
                f"no run yet: the run has not started (its board and phone are being opened), so no {what} "
                "can be carried out; try again once the page shows the run"
            )
        return None

    # ------------------------------------------------------------------ server threads
    def submit(self, body: bytes, remote: str = "") -> OperatorCommand | None:
        """Queue a request: the command, or None when :data:`INBOX` commands are already waiting.
        :class:`UplinkRefused` when no run can take it (before its start, after its end);
        :class:`InputFormatError` for a malformed request — checked before the inbox, so a malformed
        request is refused as such (and logged) whatever is waiting."""
        with self._lock:
            refusal = self._refusal("command")
            if refusal is not None:
                raise refusal
            command = parse_command(body, self._next_id, remote)
            if len(self._inbox) >= INBOX:
                self.stats.inbox_full += 1
                return None
            self._next_id += 1
            self._inbox.append(command)
            self.stats.accepted += 1
            return command

    def acknowledge(self, body: bytes, remote: str = "") -> dict[str, Any] | None:
        """Queue an alarm acknowledgement; None when :data:`INBOX` are already waiting.
        :class:`UplinkRefused` and :class:`InputFormatError` as for :meth:`submit` (parsed before the
        inbox is looked at)."""
        with self._lock:
            refusal = self._refusal("acknowledgement")
            if refusal is not None:
                raise refusal
            ack = parse_ack(body, remote)
            if len(self._acks) >= INBOX:
                self.stats.inbox_full += 1
                return None
            self._acks.append(ack)
            self.stats.acks += 1
            return ack

    def reject(self, reason: str, remote: str, detail: str = "") -> None:
        """A request the server turned away, to be logged in the run's events on the next tick."""
        with self._lock:
            self.stats.rejected += 1
            if len(self._rejected) >= REJECTED_LOG:
                self.stats.rejected_unlogged += 1
                return
            self._rejected.append({"reason": reason, "remote": remote, "detail": detail})

    def seal(self) -> None:
        """The run is over (its summary written, or it failed to start): every request is refused as
        ended from now on. A run that started was closed already (:meth:`close`); one that never started
        took nothing (:meth:`open` never came), so nothing is left without a status either way."""
        with self._lock:
            self._closed = True

    # ------------------------------------------------------------------ the control thread
    def close(self, host: Host, t: float) -> None:
        """The run's loop has ended at ``t`` (s): from now on every command is answered 409
        (:class:`UplinkClosed`), and what came after the last tick is logged as refused — a command
        answered 202 ``queued`` is never left without a status (a few were, accepted in the ~40 ms between
        the last tick and the summary, in neither the events nor the summary)."""
        with self._lock:
            self._closed = True
            commands = list(self._inbox)
            self._inbox.clear()
        for command in commands:
            host.record_command(t, command, "refused", reason="the run has ended")
        self._log_requests(host, t)  # the rejections and acknowledgements that came meanwhile

    def _log_requests(self, host: Host, t: float) -> None:
        """The requests turned away and the alarm acknowledgements since the last call, into the run's
        events."""
        with self._lock:
            rejected = list(self._rejected)
            self._rejected.clear()
            acks = list(self._acks)
            self._acks.clear()
        for r in rejected:
            host.events.write(t, "command", origin="gcs", id=None, command=None, status="rejected", **r)
        for a in acks:
            host.events.write(t, "alarm_ack", origin="gcs", **a)

    def service(self, host: Host, t: float) -> None:
        """Log rejections, carry out queued commands (:class:`~hil.runtime.operator.Operator`), settle
        answered ones; raises :class:`~hil.runtime.observer.RunAborted` once an abort's Disarm is answered
        (or cannot be sent)."""
        with self._lock:
            commands = list(self._inbox)
            self._inbox.clear()
        self._log_requests(host, t)
        for command in commands:
            self.operator.apply(host, t, command)
        self.operator.service(host, t)
