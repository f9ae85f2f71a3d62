"""Reliable commands, sans-IO: send, match the answer, retry with the same sequence number, give up.

Sender side (:class:`ReliableSender`)::

    sender = ReliableSender(framer)                 # shares the framer (sequence numbers) with setpoints
    cmd, data = sender.send(Arm(), now)             # write `data`; cmd.state is PENDING
    for event in deframer.feed(received):           # whenever bytes arrive
        if isinstance(event, Frame):
            sender.on_frame(event, now)             # an Ack/Nack (or HelloReply) settles its command
    transport.write(sender.poll(now))               # retransmissions that are due (may be b"")
    cmd.state                                       # PENDING → ACKED | NACKED (cmd.reason) | FAILED

No clock inside: every call takes ``now`` (seconds on any monotonic time base the caller uses — wall
or lockstep; one that is not finite, or too far out for a timeout to be added to it, is refused with
:class:`ConfigError`; one earlier than the latest given by more than the shortest timeout — a clock
stepped back — moves every pending try's times back with it, each keeping the wait it had left:
``SenderStats.clock_steps_back``; a smaller step back, two readings given out of order, changes
nothing), and :meth:`ReliableSender.next_deadline` says when :meth:`~ReliableSender.poll` next has work,
so an event loop can sleep exactly that long.

Rules (docs/protocol.md, "Reliable commands"):

* A reliable message (``RELIABLE = True``) goes out with ``ACK_REQUESTED`` and the next sequence
  number; the far side answers ``Ack``/``Nack`` carrying the command's ``(msg_id, seq)``, which is how
  answers are matched (several commands may be in flight at once).
* No answer within the try's timeout: the *same bytes but for the flags* are sent again — same sequence
  number, ``RETRANSMIT`` added — so a receiver that already executed the command answers from its cache
  instead of executing it twice. After ``max_tries`` sends and one more timeout the command FAILS.
* ``Hello`` is not acknowledged but answered by ``HelloReply`` (which carries no sequence number): the
  first ``HelloReply`` settles the oldest pending ``Hello``.
* An answer for a command already settled (a late answer to an earlier try) is counted, not an error.
  One for a command a newer one superseded (it failed, not knowing whether the board carried it out) is
  also kept on that command (``Command.late_reply``): it says whether the board did, and
  ``on_late_answer`` is told.

Receiver side (:class:`AnswerCache`, :func:`answer_for`): answer each ``(msg_id, seq)`` once and repeat
that answer to retransmissions.
"""

from __future__ import annotations

import enum
import math
from collections import OrderedDict, deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from .errors import CommandFailed, ConfigError, ProtocolError, value_repr
from .frame import Frame, Framer
from .messages import Ack, Flags, Hello, HelloReply, Nack, NackReason
from .numbers import real_number


class CommandState(enum.Enum):
    """Where a reliable command is. Every state but PENDING is final."""

    PENDING = "pending"  # sent, waiting for its answer (and retried while it waits)
    ACKED = "acked"  # answered with Ack (or HelloReply for Hello)
    NACKED = "nacked"  # answered with Nack: ``Command.reason`` says why
    FAILED = "failed"  # no answer after every try, or abandoned (``Command.failure`` says why)


@dataclass(frozen=True)
class RetryPolicy:
    """When to retry and when to give up.

    Try k (k = 1 … ``max_tries``) waits ``min(timeout_s · backoff^(k-1), max_timeout_s)`` seconds for
    its answer. The defaults suit a 115200-baud serial link to a board whose main loop answers within a
    few milliseconds: 5 tries over half a second, well inside the board's 250 ms link watchdog per try.
    """

    timeout_s: float = 0.1
    max_tries: int = 5
    backoff: float = 1.0
    max_timeout_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("timeout_s", "backoff", "max_timeout_s"):
            value = getattr(self, name)
            number = real_number(value)  # 10**400 was an OverflowError out of ``math.isfinite``
            if number is None or not math.isfinite(number):
                raise ConfigError(f"{value_repr(value)} is not a finite number", f"RetryPolicy.{name}")
            object.__setattr__(self, name, number)  # numpy's scalars and 0-d arrays: the float they hold
        if self.timeout_s <= 0 or self.max_timeout_s < self.timeout_s:
            got = f"got {self.timeout_s}, {self.max_timeout_s}"
            raise ConfigError(f"need 0 < timeout_s <= max_timeout_s ({got})", "RetryPolicy")
        if self.backoff < 1.0:
            raise ConfigError(f"{value_repr(self.backoff)} must be >= 1", "RetryPolicy.backoff")
        if isinstance(self.max_tries, bool) or not isinstance(self.max_tries, int) or self.max_tries < 1:
            raise ConfigError(
                f"{value_repr(self.max_tries)} must be an integer >= 1", "RetryPolicy.max_tries"
            )

    def timeout(self, tries: int) -> float:
        """Seconds to wait for an answer after the ``tries``-th send.

        A power past the float range is ``max_timeout_s`` (the backoff is at least 1: it only grows): a
        float power raises ``OverflowError`` there rather than giving inf — a backoff of 1e160 at the third
        try, a backoff of 2 at the 1025th — and the retry loop died with a traceback instead of retrying
        or failing the command."""
        try:
            grown = self.backoff ** (tries - 1)
        except OverflowError:
            return self.max_timeout_s
        return min(self.timeout_s * grown, self.max_timeout_s)


@dataclass(eq=False)
class Command:
    """The handle of one reliable command: poll its ``state``, or be told through ``on_settled``.

    Times are on the caller's time base (seconds)."""

    message: Any
    seq: int
    sent_at: float  # first send
    deadline: float  # when the current try times out
    tries: int = 1
    last_sent_at: float = 0.0
    state: CommandState = CommandState.PENDING
    reply: Any = None  # the Ack, Nack or HelloReply that settled it
    reason: NackReason | None = None  # for NACKED
    failure: str = ""  # for FAILED
    settled_at: float | None = None
    superseded_by: Command | None = None  # the newer command that superseded it (then FAILED, not retried)
    late_reply: Any = None  # a superseded command's Ack or Nack, come after it was superseded

    @property
    def carried_out(self) -> bool | None:
        """Whether the board carried the command out: True once Acked (or a superseded one's late Ack),
        False once Nacked (or a superseded one's late Nack), None while not known (pending, no answer)."""
        reply = self.reply if self.state is not CommandState.FAILED else self.late_reply
        if isinstance(reply, Nack):
            return False
        return True if reply is not None else None

    @property
    def msg_id(self) -> int:
        return int(self.message.MSG_ID)

    @property
    def key(self) -> tuple[int, int]:
        """``(msg_id, seq)``: what an Ack/Nack names."""
        return (self.msg_id, self.seq)

    @property
    def done(self) -> bool:
        return self.state is not CommandState.PENDING

    @property
    def ok(self) -> bool:
        return self.state is CommandState.ACKED

    @property
    def latency(self) -> float | None:
        """Seconds from the first send to the answer (None unless answered)."""
        if self.settled_at is None or self.state is CommandState.FAILED:
            return None
        return self.settled_at - self.sent_at

    def result(self) -> Any:
        """The answering message if ACKED; raises :class:`CommandFailed` if NACKED or FAILED and
        :class:`ProtocolError` while still PENDING."""
        name = type(self.message).__name__
        if self.state is CommandState.ACKED:
            return self.reply
        if self.state is CommandState.NACKED:
            assert self.reason is not None
            raise CommandFailed(f"{name} (seq {self.seq}) refused: {self.reason.name}")
        if self.state is CommandState.FAILED:
            raise CommandFailed(f"{name} (seq {self.seq}) failed: {self.failure}")
        raise ProtocolError(f"{name} (seq {self.seq}) is still pending")

    def __repr__(self) -> str:
        extra = self.reason.name if self.reason is not None else self.failure
        return (
            f"Command({type(self.message).__name__}, seq={self.seq}, {self.state.value}, tries={self.tries}"
            f"{', ' + extra if extra else ''})"
        )


@dataclass
class SenderStats:
    """What a :class:`ReliableSender` has done (all counts since construction)."""

    sent: int = 0  # commands sent (first tries)
    retransmits: int = 0  # retries sent
    acked: int = 0
    nacked: int = 0
    failed: int = 0
    late_answers: int = 0  # answers for commands already settled (e.g. the answer to an earlier try)
    unmatched_answers: int = 0  # answers naming no command this sender knows
    superseded: int = 0  # pending commands failed by a newer one setting the same thing (not retried)
    clock_steps_back: int = 0  # calls whose ``now`` was a timeout or more before the latest (times moved)


_RECENT = 256  # settled commands remembered to tell a late answer from an unmatched one
_SEND_ROOM = 4.0
"""Float steps a command's shortest timeout spans at least when it is sent: its retries' times may cross
into the next binade (steps twice as long) and still leave its timeouts room (unless the command's whole
life, ``max_tries · max_timeout_s``, is as long as the time itself: ~10¹³ s for a 0.1 s timeout)."""


class ReliableSender:
    """Tracks reliable commands through their answers and retries; see the module docstring.

    ``framer`` numbers frames; share it with everything else this end sends (setpoints, heartbeats) so
    the receiver sees one sequence. ``on_settled`` (optional) is called once per command when it
    leaves PENDING, from inside :meth:`on_frame`, :meth:`poll` or :meth:`abandon`. An exception it
    raises comes out of that call, the sender's own state kept whole: :meth:`poll` takes back the
    retransmissions it had not returned (still due, the next poll sends them), and :meth:`abandon`
    settles and tells every command before raising the first error.
    """

    def __init__(
        self,
        framer: Framer | None = None,
        policy: RetryPolicy | None = None,
        on_settled: Callable[[Command], None] | None = None,
        on_late_answer: Callable[[Command], None] | None = None,
    ) -> None:
        self.framer = framer if framer is not None else Framer()
        self.policy = policy if policy is not None else RetryPolicy()
        self.on_settled = on_settled
        self.on_late_answer = on_late_answer
        self.stats = SenderStats()
        # commands superseded lately, by key: their late answers say whether the board carried them out
        self._superseded: OrderedDict[tuple[int, int], Command] = OrderedDict()
        self._pending: OrderedDict[tuple[int, int], Command] = OrderedDict()
        self._recent: deque[tuple[int, int]] = deque(maxlen=_RECENT)
        self._clock: float | None = None  # the latest ``now`` given (s)

    # ------------------------------------------------------------------ sending
    def send(self, message: Any, now: float) -> tuple[Command, bytes]:
        """Frame ``message`` with the next sequence number; returns its handle and the bytes to write.

        Raises :class:`ProtocolError` for a message that is never answered (send those with
        ``framer.encode``) and :class:`FieldRangeError` for an out-of-range field."""
        self._check_now(now, "ReliableSender.send", room=_SEND_ROOM)
        if not expects_answer(message):
            raise ProtocolError(
                f"{type(message).__name__} is not acknowledged; send it with Framer.encode (no retries)"
            )
        seq, data = self.framer.encode(message)
        cmd = Command(message, seq, sent_at=now, deadline=now + self.policy.timeout(1), last_sent_at=now)
        self._superseded.pop(cmd.key, None)  # a late answer with this key is the new command's now
        stale = self._pending.pop(cmd.key, None)
        # Pending before any older one is settled: a command ``on_settled`` sends meanwhile is the newer one
        # and supersedes this one, rather than both being retried side by side.
        self._pending[cmd.key] = cmd
        self.stats.sent += 1
        try:
            if stale is not None:  # 256 frames went out while it waited: its answers are now ambiguous
                self._settle(
                    stale, CommandState.FAILED, now, failure="sequence number reused by a newer command"
                )
            self._supersede(cmd, now)
        except BaseException as exc:
            self._withdraw(cmd, now, exc)
            raise
        return cmd, data

    def poll(self, now: float) -> bytes:
        """Retransmissions due at ``now`` (concatenated wire bytes, possibly empty); commands whose last
        try has timed out become FAILED.

        The commands due are taken at the call, but one may leave PENDING before its turn: ``on_settled``,
        told of an earlier one failing, may send a command that supersedes it or abandon them all (the
        session's handshake failure takes the link down). Such a one is not sent again — a superseded
        Disarm was retried after the Arm that superseded it — nor settled twice (which raised
        ``KeyError``)."""
        self._check_now(now, "ReliableSender.poll")
        out = bytearray()
        # retransmitted here: (command, its deadline and last send before)
        sent: list[tuple[Command, float, float]] = []
        try:
            for cmd in [c for c in self._pending.values() if c.deadline <= now]:
                if self._pending.get(cmd.key) is not cmd:
                    continue  # settled meanwhile, from a callback of one polled before it
                if cmd.tries >= self.policy.max_tries:
                    del self._pending[cmd.key]
                    self._settle(cmd, CommandState.FAILED, now, failure=f"no answer after {cmd.tries} tries")
                    continue
                _, data = self.framer.encode(cmd.message, seq=cmd.seq)
                sent.append((cmd, cmd.deadline, cmd.last_sent_at))
                cmd.tries += 1
                cmd.last_sent_at = now
                cmd.deadline = now + self.policy.timeout(cmd.tries)
                self.stats.retransmits += 1
                out += data
        except BaseException:
            # ``on_settled`` raised: the bytes gathered are never returned, so those tries were not sent.
            # Counted as sent, each waited a whole timeout before its next try, and the last try of a
            # command failed it after one try fewer than its policy's, unseen by the board.
            for cmd, deadline, last_sent_at in sent:
                cmd.tries -= 1
                cmd.deadline, cmd.last_sent_at = deadline, last_sent_at
                self.stats.retransmits -= 1
            raise
        return bytes(out)

    def _withdraw(self, cmd: Command, now: float, exc: BaseException) -> None:
        """Take back ``cmd``, whose :meth:`send` raises ``exc`` (``on_settled``, told of an older command
        it settled, raised): the caller never gets its handle nor its bytes, so it must not go out later.
        Left pending, it went out as a retransmission a timeout later — a Disarm the caller was told had
        not been sent, carried out, and its tries counting one the board never saw. It fails untold (its
        sequence number stays used: the receiver sees a gap, as for a lost frame)."""
        if self._pending.get(cmd.key) is not cmd:
            return  # settled meanwhile: a command the callback sent superseded it
        del self._pending[cmd.key]
        self.stats.sent -= 1
        cmd.state, cmd.settled_at = CommandState.FAILED, now
        cmd.failure = f"never sent: on_settled raised {type(exc).__name__} while it was being sent"

    def next_deadline(self) -> float | None:
        """The earliest time :meth:`poll` has work (None when nothing is pending)."""
        return min((c.deadline for c in self._pending.values()), default=None)

    # ------------------------------------------------------------------ receiving
    def on_frame(self, frame: Frame, now: float) -> Command | None:
        """Offer a received frame; returns the command it settled, if any. Frames that are not answers
        are ignored (returns None), so every received frame may be passed here.

        An Ack or Nack naming a pending ``Hello`` answers nothing: a Hello is answered by ``HelloReply``
        alone (it requests no Ack). It settled the handshake ACKED with an Ack for its reply — no board
        identity, state or schema hash in it, ``result()`` not the ``HelloReply`` it promises — or NACKED,
        and the Hello was never retried; it is counted as unmatched and the Hello waits on."""
        self._check_now(now, "ReliableSender.on_frame")
        msg = frame.message
        if isinstance(msg, (Ack, Nack)):
            key = (msg.msg_id, msg.seq)
            answered = self._pending.get(key)
            cmd = None if answered is None or isinstance(answered.message, Hello) else self._pending.pop(key)
            if cmd is None:
                self._count_stray(key)
                self._superseded_answer(key, msg)
                return None
            if isinstance(msg, Ack):
                return self._settle(cmd, CommandState.ACKED, now, reply=msg)
            return self._settle(cmd, CommandState.NACKED, now, reply=msg, reason=msg.reason)
        if isinstance(msg, HelloReply):
            cmd = next((c for c in self._pending.values() if isinstance(c.message, Hello)), None)
            if cmd is None:
                self._count_stray((HelloReply.MSG_ID, -1))
                return None
            del self._pending[cmd.key]
            return self._settle(cmd, CommandState.ACKED, now, reply=msg)
        return None

    def abandon(self, now: float, why: str = "abandoned") -> list[Command]:
        """Fail every pending command (e.g. the link was lost or the board reset); returns them."""
        self._check_now(now, "ReliableSender.abandon")
        cmds = list(self._pending.values())
        self._pending.clear()
        first_error: BaseException | None = None
        for cmd in cmds:  # every one settled and told, whatever a callback raises: none left PENDING untold
            try:
                self._settle(cmd, CommandState.FAILED, now, failure=why)
            except Exception as exc:  # ``on_settled``'s: raised once all are settled
                first_error = exc if first_error is None else first_error
        if first_error is not None:
            raise first_error
        return cmds

    # ------------------------------------------------------------------ inspection
    @property
    def pending(self) -> list[Command]:
        """Commands still waiting for an answer, oldest first."""
        return list(self._pending.values())

    def __iter__(self) -> Iterator[Command]:
        return iter(self.pending)

    def __len__(self) -> int:
        return len(self._pending)

    # ------------------------------------------------------------------ internals
    def _check_now(self, now: float, where: str, room: float = 1.0) -> None:
        """Refuse a time (s) a try's deadline cannot be set from, naming ``where`` it was given.

        Not a finite number: a command sent at NaN had a NaN deadline — no later time is past it — so it
        was never retried and never failed (pending for ever, ``next_deadline`` NaN); a poll at NaN did
        nothing, silently; one at ``inf`` put every deadline at inf, the same hang one poll later. So far
        from zero that the policy's shortest timeout is lost in the rounding of ``now + timeout`` (beyond
        ~1e15 s for 0.1 s; a time in ns taken for s): every try timed out the moment it was sent, and a
        command failed after all its tries at one instant, never waiting for an answer. (The longer
        timeouts of later tries, ``timeout_s`` or more, are then never lost either.)

        ``room``: what the shortest timeout is divided by and must still move ``now`` by. :meth:`send`
        asks for :data:`_SEND_ROOM`, the other calls for one: a command's retries move the clock on, and
        accepted with one step to spare, a command sent just below 2**53 s had its own next deadline
        refused by :meth:`poll` (the steps double there). A bool or an integer past a float's range (an
        ``OverflowError``) is no time either."""
        seconds = real_number(now)  # any real number: a float, an int, numpy's scalars
        if seconds is None or not math.isfinite(seconds):
            raise ConfigError(f"a time must be a finite number of seconds, not {value_repr(now)}", where)
        now = seconds
        policy = self.policy
        if not now + policy.timeout_s / room > now:
            raise ConfigError(
                f"a time of {value_repr(now)} s leaves no room for a {policy.timeout_s} s timeout (floats "
                f"{math.ulp(now)} s apart there; {room:g} of them needed): not a time on a clock of seconds",
                where,
            )
        self._follow_clock(now)

    def _follow_clock(self, now: float) -> None:
        """Take ``now`` (s) as the latest time. One earlier than the latest given by more than the policy's
        shortest timeout — a clock stepped back — moves every pending command's times (first and last
        send, deadline) back by the step, so each try keeps the wait it had left. Kept where they were, a
        clock stepped back by a minute left every command waiting a minute past its timeout — nothing
        retried, nothing failed, the caller's ``next_deadline`` far ahead — and a try sent meanwhile (a new
        command) timed out after the older ones that should have come first. A step back within the
        shortest timeout is two callers' readings of one clock taken in one order and given in the other
        (a reader thread's and the caller's loop's): it costs a try at most that much more wait, and is
        left alone (the latest time kept), or such jitter, each step moving every deadline back, would
        pull the tries ever earlier."""
        latest = self._clock
        if latest is None or now >= latest:
            self._clock = now
            return
        if latest - now <= self.policy.timeout_s:
            return
        self._clock = now
        step = now - latest
        self.stats.clock_steps_back += 1
        for cmd in self._pending.values():
            cmd.sent_at += step
            cmd.last_sent_at += step
            cmd.deadline += step

    def _supersede(self, cmd: Command, now: float) -> None:
        """Stop retrying the pending commands that set what ``cmd`` sets (the message's ``SETS``): they
        fail, superseded. A Disarm sent into a stalled link, then an Arm: retried after the Arm was carried
        out, the Disarm left the board disarmed though the host's last word was Arm. (One already on its
        way is the receiver's to order; one not yet carried out is not sent again.)

        Whether the board carried a superseded one out is not known when it is superseded — a try may be
        on its way, or carried out with its answer still coming: its failure says so, never that it was
        not carried out, and its answer, if one comes, is kept on it (:meth:`_superseded_answer`). A
        Disarm the board did carry out was said to have failed, its Ack only counted as a late answer."""
        sets = getattr(cmd.message, "SETS", None)
        if sets is None:
            return
        older = [
            c for c in self._pending.values() if getattr(c.message, "SETS", None) == sets and c is not cmd
        ]
        for old in older:
            if self._pending.get(old.key) is not old:
                continue  # settled meanwhile, from the callback of one superseded before it
            del self._pending[old.key]
            self.stats.superseded += 1
            old.superseded_by = cmd
            tries = f"{old.tries} {'try' if old.tries == 1 else 'tries'}"
            what = (
                f"superseded by a newer {type(cmd.message).__name__} (seq {cmd.seq}) and not sent again; "
                f"no answer yet to its {tries}: whether the board carried it out is not known"
            )
            self._superseded[old.key] = old
            while len(self._superseded) > _RECENT:
                self._superseded.popitem(last=False)
            self._settle(old, CommandState.FAILED, now, failure=what)

    def _superseded_answer(self, key: tuple[int, int], answer: Ack | Nack) -> None:
        """A superseded command's answer, come late: kept on it (``late_reply``, ``carried_out``), its
        failure saying what the board did, and ``on_late_answer`` told."""
        cmd = self._superseded.pop(key, None)
        if cmd is None:
            return
        cmd.late_reply = answer
        newer = cmd.superseded_by
        by = "" if newer is None else f" by a newer {type(newer.message).__name__} (seq {newer.seq})"
        did = (
            "the board carried it out (its Ack came late)"
            if isinstance(answer, Ack)
            else f"the board refused it (its Nack came late: {getattr(answer.reason, 'name', answer.reason)})"
        )
        cmd.failure = f"superseded{by} and not sent again; {did}"
        if self.on_late_answer is not None:
            self.on_late_answer(cmd)

    def _settle(
        self,
        cmd: Command,
        state: CommandState,
        now: float,
        *,
        reply: Any = None,
        reason: NackReason | None = None,
        failure: str = "",
    ) -> Command:
        cmd.state, cmd.reply, cmd.reason, cmd.failure, cmd.settled_at = state, reply, reason, failure, now
        if state is CommandState.ACKED:
            self.stats.acked += 1
        elif state is CommandState.NACKED:
            self.stats.nacked += 1
        else:
            self.stats.failed += 1
        self._recent.append(cmd.key if not isinstance(cmd.message, Hello) else (HelloReply.MSG_ID, -1))
        if self.on_settled is not None:
            self.on_settled(cmd)
        return cmd

    def _count_stray(self, key: tuple[int, int]) -> None:
        if key in self._recent:
            self.stats.late_answers += 1
        else:
            self.stats.unmatched_answers += 1


def expects_answer(message: Any) -> bool:
    """True for messages the far side answers: the reliable ones (Ack/Nack) and Hello (HelloReply)."""
    return bool(getattr(message, "RELIABLE", False)) or isinstance(message, Hello)


# =========================================================================== receiver side
def answer_for(frame: Frame, refused: NackReason | None) -> Ack | Nack:
    """The answer to a reliable ``frame``: Ack if ``refused`` is None, else Nack with that reason."""
    if refused is None:
        return Ack(msg_id=frame.msg_id, seq=frame.seq)
    return Nack(msg_id=frame.msg_id, seq=frame.seq, reason=refused)


@dataclass
class AnswerCache:
    """Receiver side: remembers the answer given to the last ``entries`` reliable commands so a
    retransmission (``RETRANSMIT`` flag, same ``(msg_id, seq)`` *and* same content) is answered again
    without executing the command twice. A different command reusing the key is executed anew."""

    entries: int = 32
    duplicates: int = 0  # retransmissions answered from the cache
    _answers: OrderedDict[tuple[int, int], tuple[Any, Any]] = field(default_factory=OrderedDict, repr=False)

    def __post_init__(self) -> None:
        if isinstance(self.entries, bool) or not isinstance(self.entries, int) or self.entries < 1:
            raise ConfigError(f"{value_repr(self.entries)} must be an integer >= 1", "AnswerCache.entries")

    def lookup(self, frame: Frame) -> Ack | Nack | None:
        """The answer already given to this retransmitted command, or None: execute it."""
        if not frame.flags & Flags.RETRANSMIT:
            return None
        hit = self._answers.get((frame.msg_id, frame.seq))
        if hit is None or hit[0] != frame.message:
            return None
        self.duplicates += 1
        answer: Ack | Nack = hit[1]
        return answer

    def remember(self, frame: Frame, answer: Ack | Nack) -> None:
        key = (frame.msg_id, frame.seq)
        self._answers[key] = (frame.message, answer)
        self._answers.move_to_end(key)
        while len(self._answers) > self.entries:
            self._answers.popitem(last=False)

    def clear(self) -> None:
        """Forget every answer (a new session: sequence numbers restart)."""
        self._answers.clear()


__all__ = [
    "AnswerCache",
    "Command",
    "CommandState",
    "ReliableSender",
    "RetryPolicy",
    "SenderStats",
    "answer_for",
    "expects_answer",
]
