"""A user's phone source, held to its interface: :class:`CheckedSource` wraps a source that another package
registered (:func:`hil.link.sources.create_source` builds every scheme but ``hil``'s own through it), so
that whatever it does wrong mid-run ends the run with a :class:`~hil.plugins.PluginError` naming it, what
it did and when — never a traceback from deep in the host, or a summary that never got written.

What is checked, each call:

=========================  ========================================================================
call                       checked
=========================  ========================================================================
``drain(now)``             a list (or tuple) of at most :data:`MAX_DRAIN`
                           :class:`~hil.estimation.sensors.SensorSample`, each with a time stamp that
                           is a real number, a ``SensorKind``, and three real numbers; passed on as
                           floats (an ``int`` stamp, a numpy row of ``xyz``)
``truth(now)``             None or a :class:`~.base.GroundTruth` (or an object with ``R`` and
                           ``omega``): ``R`` a finite rotation (3, 3), ``omega`` a finite (3,) within
                           the estimates' bound (:data:`~hil.estimation.checked.RATE_LIMIT`)
``rate_hz``                None or a rate the estimator task can run at: :data:`MIN_RATE_HZ` to
                           :data:`MAX_RATE_HZ`, as a scenario's phone
``start(origin)``          None or a finite end time not before ``origin``
``tasks()``                a list of :class:`~hil.timing.scheduler.PeriodicTask`, each callback wrapped
``senders()``              None or a :class:`~.base.SenderStatus` of a string, counts and a bool,
                           whose events are :class:`~.base.SenderEvent` s of the one-phone rule's
                           kinds (:data:`SENDER_KINDS`), their fields JSON keyed by strings other
                           than ``t`` and ``kind`` (the record's own)
``report()``               a dict of sections, each a dict whose keys are strings, JSON (at most
                           :data:`~hil.plugins.MAX_DEPTH` deep); merged by :func:`merge_report`
                           as sections of its own, never one the run writes
=========================  ========================================================================

A sample that is a ``SensorSample`` of the right types but absurd — a NaN or infinite stamp or value, a
reading beyond any phone's range, stamped out of order, a duplicate — is passed on: the host's admission
policy (:mod:`hil.estimation.admission`) drops and counts it, as it does a live phone's.

Anything the source raises that is not the project's own (a :class:`~protocol.errors.HilError`, such
as :meth:`~.base.PhoneSource.wait_ready`'s ``LinkTimeout`` or a receiver thread's ``LinkError``, passes as
it is) — its own exception, Python's, a ``sys.exit()``, in a call or as what it returned is read —
becomes a :class:`~hil.plugins.PluginError` ``from`` it (:func:`~hil.plugins.call_plugin`); Ctrl-C
(KeyboardInterrupt) passes through. ``hil``'s own schemes are not wrapped: no cost on their path.

Its mid-run calls (``drain``, ``truth``, ``advance``, its tasks' callbacks, ``senders``, ``exhausted``) run on
a thread of the source's own and are waited for :data:`LIVE_CALL_WAIT_S` of wall time
(:class:`~hil.plugin_worker.PluginWorker`): one that never returns (a socket read with no timeout, a lock) is
a :class:`~hil.plugins.PluginTimeout` naming the call and its time — it hung ``hil run`` until it was killed,
as an estimator's step did. ``wait_ready`` has its own bound (the run's phone wait) and is called directly, as
are the set-up's and the ending's calls."""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from numbers import Real
from typing import TYPE_CHECKING, Any

import numpy as np

from hil.estimation.checked import RATE_LIMIT, STEP_WAIT_FLOOR_S, rotation_fault
from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.base import GroundTruth, PhoneSource, SenderEvent, SenderStatus
from hil.link.sources.stream import MAX_QUEUE
from hil.numbers import finite_number
from hil.plugin_worker import PluginWorker
from hil.plugins import PluginError, call_plugin, describe_value, json_plain
from hil.scenario.reader import MIN_NEEDED_SENSOR_RATE_HZ, RANGES
from protocol.errors import HilError

if TYPE_CHECKING:
    from hil.timing.scheduler import PeriodicTask


SENDER_KINDS = frozenset({"phone_other", "phone_following", "phone_switch"})
"""The ``events.jsonl`` kinds of the one-phone rule (docs/formats.md, "One phone per receiver"): the only
ones a source's :meth:`~.base.PhoneSource.senders` may write (a user's "disarmed" is no record of the
board's)."""

LIVE_CALL_WAIT_S = STEP_WAIT_FLOOR_S
"""s of wall time a source's mid-run call is waited for (an estimator's floor: a drain is a few ms, one
that takes half a minute is stuck, not slow)."""

MIN_RATE_HZ = MIN_NEEDED_SENSOR_RATE_HZ
"""The slowest ``rate_hz`` a source may give (Hz): the estimator task drains it at that rate, and slower
than two drains within the host's staleness bound every interval between drains is a phone gap — a source
that said 0.01 Hz was drained every 100 s and the run ended "lost: phone" 15 s in, naming no plugin."""

MAX_RATE_HZ = RANGES["sensors.*.rate_hz"][1]
"""The fastest ``rate_hz`` a source may give (Hz): a scenario's fastest phone sensor. 1e300 Hz ended the run
on the scheduler's "task 'estimator': period must be at least 1 ns", naming no plugin; 1e6 Hz drained it a
million times a simulated second."""

MAX_DRAIN = 16 * MAX_QUEUE
"""Samples one ``drain`` may hand over (65 536: 20 s of three sensors at 1 kHz, sixteen times what a live
receiver holds at most, :data:`~.stream.MAX_QUEUE`): a source holds the rest of a burst for the next call
(:meth:`~.base.PhoneSource.drain`'s bounded batch). A drain of millions was checked sample by sample,
copied, sorted and fed on the control thread — memory and a stalled control loop without bound, one
drain after another; now it is the source's :class:`~hil.plugins.PluginError`, read by its length alone."""

_COUNTS = ("phone_switches", "other_phones", "other_phone_messages", "other_phone_samples")


def _real(value: Any) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool)


def _finite(value: Any) -> float | None:
    """``value`` as a float if it is a finite real number (a numpy scalar too), else None: not a bool, and
    not an int past a float's range (``float`` of one raises OverflowError)."""
    if not _real(value):
        return None
    try:
        return finite_number(float(value))
    except OverflowError:
        return None


class CheckedSource(PhoneSource):
    """``inner``, a user's :class:`~.base.PhoneSource`, with every call checked (see the module docstring);
    ``scheme`` is its registered scheme, for the errors."""

    def __init__(self, inner: PhoneSource, scheme: str) -> None:
        self.inner = inner
        self.scheme = scheme
        self.plugin = f"phone source {scheme!r}"
        self.url = str(getattr(inner, "url", f"{scheme}://"))
        self.worker = PluginWorker(self.plugin)

    def __repr__(self) -> str:
        return f"CheckedSource({self.inner!r}, {self.scheme!r})"

    def _error(self, detail: str) -> PluginError:
        return PluginError(self.plugin, detail)

    def _call(self, what: str, call: Callable[[], Any]) -> Any:
        # the project's own (a LinkTimeout, a PluginError of a wrapped call) pass as raised
        return call_plugin(self.plugin, what, call, HilError)

    def _live(self, what: str, call: Callable[[], Any]) -> Any:
        """``call()``, one of the run's mid-run calls, on the source's worker thread, waited for
        :data:`LIVE_CALL_WAIT_S`."""
        return self._call(what, lambda: self.worker.call(what, call, LIVE_CALL_WAIT_S))

    # ------------------------------------------------------------------ samples and truth
    def drain(self, now: float) -> list[SensorSample]:
        where = f"drain at t = {now:.6f} s"
        out = self._live(where, lambda: self.inner.drain(now))
        return self._call(f"{where}: reading what it returned", lambda: self._samples(out, where))  # type: ignore[no-any-return]

    def _samples(self, out: Any, where: str) -> list[SensorSample]:
        if type(out) is not list:
            if not isinstance(out, (list, tuple)):
                raise self._error(f"{where} returned {describe_value(out)}, not a list of SensorSamples")
            if len(out) <= MAX_DRAIN:  # a longer one is refused below, never copied
                out = list(out)
        if len(out) > MAX_DRAIN:
            raise self._error(
                f"{where} returned {len(out)} samples, more than {MAX_DRAIN} in one call: a source hands "
                "over a bounded batch and holds the rest of a burst for the next drain"
            )
        for i, s in enumerate(out):
            if not (
                type(s) is SensorSample
                and type(s.t_s) is float
                and type(s.kind) is SensorKind
                and type(s.xyz) is tuple
                and len(s.xyz) == 3
                and type(s.xyz[0]) is float
                and type(s.xyz[1]) is float
                and type(s.xyz[2]) is float
            ):
                out[i] = self._sample(s, f"{where} returned, at [{i}] of {len(out)},")
        return out  # type: ignore[no-any-return]

    def _sample(self, s: Any, where: str) -> SensorSample:
        """``s`` as a SensorSample of floats, if it is one of real numbers."""
        if not isinstance(s, SensorSample):
            raise self._error(f"{where} {describe_value(s)}, not a SensorSample")
        if not _real(s.t_s):
            raise self._error(f"{where} a sample stamped {describe_value(s.t_s)}, not a number of seconds")
        if not isinstance(s.kind, SensorKind):
            raise self._error(f"{where} a sample of kind {describe_value(s.kind)}, not a SensorKind")
        xyz = s.xyz
        try:
            values = tuple(xyz)
        except TypeError:
            values = ()
        if len(values) != 3 or not all(map(_real, values)):
            raise self._error(f"{where} a {s.kind.label} sample of {describe_value(xyz)}, not three numbers")
        try:
            x, y, z = (float(v) for v in values)
            return SensorSample(float(s.t_s), s.kind, (x, y, z))
        except (TypeError, ValueError, OverflowError) as exc:  # a Real that float() refuses
            raise self._error(f"{where} a sample that is not floats: {exc}") from exc

    def truth(self, now: float) -> GroundTruth | None:
        where = f"truth at t = {now:.6f} s"
        found = self._live(where, lambda: self.inner.truth(now))
        if found is None:
            return None
        return self._call(f"{where}: reading what it returned", lambda: self._truth(found, where))  # type: ignore[no-any-return]

    def _truth(self, found: Any, where: str) -> GroundTruth:
        if not (hasattr(found, "R") and hasattr(found, "omega")):
            raise self._error(f"{where} returned {describe_value(found)}, not a GroundTruth or None")
        try:
            R = np.array(found.R, dtype=float)
            omega = np.array(found.omega, dtype=float)
        except (TypeError, ValueError, OverflowError) as exc:  # an int past a float's range too
            raise self._error(f"{where} returned a truth that is not numbers: {exc}") from exc
        if R.shape != (3, 3) or omega.shape != (3,):
            raise self._error(f"{where} returned R {R.shape}, omega {omega.shape}; wants (3, 3), (3,)")
        if not (np.isfinite(R).all() and np.isfinite(omega).all()):
            raise self._error(f"{where} returned a non-finite {'R' if not np.isfinite(R).all() else 'omega'}")
        fastest = float(np.abs(omega).max())
        if not fastest <= RATE_LIMIT:  # the run's true rate, beside the estimates held to the same bound
            raise self._error(
                f"{where} returned omega of {fastest:.6g} rad/s on an axis, beyond any spacecraft's (the "
                f"gyroscope's bound, {RATE_LIMIT:g} rad/s)"
            )
        fault = rotation_fault(tuple(float(v) for v in R.reshape(9)))
        if fault is not None:
            raise self._error(f"{where} returned an attitude that is not a rotation: {fault}")
        return GroundTruth(R, omega)

    def close(self) -> None:
        self._call("close", self.inner.close)

    # ------------------------------------------------------------------ what the runtime asks
    @property
    def rate_hz(self) -> float | None:
        rate = self._call("rate_hz", lambda: self.inner.rate_hz)
        if rate is None:
            return None
        return self._call("rate_hz: reading what it returned", lambda: self._rate(rate))  # type: ignore[no-any-return]

    def _rate(self, rate: Any) -> float:
        """``rate``, what ``rate_hz`` gave, as Hz if the estimator task can drain the source at it."""
        hz = _finite(rate)
        if hz is None or not MIN_RATE_HZ <= hz <= MAX_RATE_HZ:
            raise self._error(
                f"rate_hz is {describe_value(rate)}, not None or a rate the estimator task can drain it at "
                f"({MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz)"
            )
        return hz

    def wait_ready(self, wait_s: float, keep_alive: Callable[[], None]) -> None:
        self._call("wait_ready", lambda: self.inner.wait_ready(wait_s, keep_alive))

    def tasks(self) -> list[PeriodicTask]:
        from dataclasses import replace

        from hil.timing.scheduler import PeriodicTask

        tasks = self._call("tasks", self.inner.tasks)
        if not isinstance(tasks, (list, tuple)) or not all(isinstance(t, PeriodicTask) for t in tasks):
            raise self._error(f"tasks returned {describe_value(tasks)}, not a list of PeriodicTasks")
        return [replace(task, callback=self._task(task)) for task in tasks]

    def _task(self, task: PeriodicTask) -> Callable[[float], None]:
        callback, name = task.callback, task.name

        def checked(due: float) -> None:
            self._live(f"its task {name!r} at t = {due:.6f} s", lambda: callback(due))

        return checked

    def advance(self, now: float) -> None:
        self._live(f"advance at t = {now:.6f} s", lambda: self.inner.advance(now))

    def start(self, origin: float) -> float | None:
        where = f"start at t = {origin:.6f} s"
        end = self._call(where, lambda: self.inner.start(origin))
        if end is None:
            return None
        return self._call(f"{where}: reading what it returned", lambda: self._end(end, origin, where))  # type: ignore[no-any-return]

    def _end(self, end: Any, origin: float, where: str) -> float:
        """``end``, what ``start(origin)`` returned, as a run time (s) if it is one not before ``origin``."""
        t = _finite(end)
        if t is None:
            raise self._error(f"{where} returned {describe_value(end)}, not None or an end time (s)")
        if not t >= origin:  # the run ended as it began, "time limit (the slew never started)"
            raise self._error(f"{where} returned an end time {t!r} s, before the run's start")
        return t

    @property
    def exhausted(self) -> bool:
        return bool(self._live("exhausted", lambda: bool(self.inner.exhausted)))

    def senders(self) -> SenderStatus | None:
        status = self._live("senders", self.inner.senders)
        if status is None:
            return None
        return self._call("senders: reading what it returned", lambda: self._senders(status))  # type: ignore[no-any-return]

    def _senders(self, status: Any) -> SenderStatus:
        """``status`` rebuilt of plain values, if it is a SenderStatus whose events the run can write."""
        if not isinstance(status, SenderStatus):
            raise self._error(f"senders returned {describe_value(status)}, not a SenderStatus or None")
        counts = [getattr(status, name) for name in _COUNTS]
        if not (
            isinstance(status.following, str)
            and all(type(n) is int and n >= 0 for n in counts)
            and isinstance(status.others_streaming, bool)
            and isinstance(status.events, (tuple, list))
        ):
            raise self._error(f"senders returned {describe_value(status)}, not a string, counts, a bool")
        events = []
        for i, event in enumerate(status.events):
            where = f"senders returned, at events[{i}],"
            if not isinstance(event, SenderEvent):
                raise self._error(f"{where} {describe_value(event)}, not a SenderEvent")
            if event.kind not in SENDER_KINDS:
                kinds = ", ".join(sorted(SENDER_KINDS))
                raise self._error(f"{where} an event of kind {describe_value(event.kind)}, not {kinds}")
            if not isinstance(event.fields, Mapping):
                raise self._error(f"{where} fields {describe_value(event.fields)}, not a mapping")
            taken = sorted({"t", "kind"} & set(event.fields))
            if taken:
                raise self._error(f"{where} a field {taken[0]!r}: the record's own (its time, its kind)")
            try:
                fields = json_plain(dict(event.fields))
            except (TypeError, ValueError) as exc:
                raise self._error(f"{where} fields events.jsonl cannot hold: {exc}") from exc
            events.append(SenderEvent(str(event.kind), fields))
        return SenderStatus(
            following=str(status.following),
            **{name: int(n) for name, n in zip(_COUNTS, counts, strict=True)},
            others_streaming=bool(status.others_streaming),
            events=tuple(events),
        )

    def report(self) -> dict[str, dict[str, Any]]:
        report = self._call("report", self.inner.report)
        return self._call("report: reading what it returned", lambda: self._report(report))  # type: ignore[no-any-return]

    def _report(self, report: Any) -> dict[str, dict[str, Any]]:
        """``report`` as plain JSON (a copy), if it is a dict of sections summary.json can hold."""
        if not isinstance(report, dict) or not all(
            isinstance(k, str) and isinstance(v, dict) and all(isinstance(f, str) for f in v)
            for k, v in report.items()
        ):
            raise self._error(f"report returned {describe_value(report)}, not a dict of sections (dicts)")
        try:
            plain: dict[str, dict[str, Any]] = json_plain(report)
        except (TypeError, ValueError) as exc:
            raise self._error(f"report returned what summary.json cannot hold: {exc}") from exc
        return plain


def merge_report(summary: dict[str, Any], source: PhoneSource, later: Collection[str] = ()) -> None:
    """``source``'s :meth:`~.base.PhoneSource.report` merged into the run's ``summary``: ``hil``'s own
    sources add fields to their sections (a receiver's ``phone``, a recording's ``samples_released`` in the
    run's ``replay``); a user's (a :class:`CheckedSource`) only adds sections of its own — a section named
    as a key the run wrote (in ``summary`` already) or writes after (``later``) is a
    :class:`~hil.plugins.PluginError`, none of it merged. A plugin's ``final_disarm``, ``link`` or
    ``phone_admission`` replaced the host's own safety record; a ``source``, ``exit`` or ``mode`` (a string)
    crashed the run's ending, no summary.json written."""
    reported = source.report()
    if not isinstance(source, CheckedSource):
        for section, fields in reported.items():
            summary.setdefault(section, {}).update(fields)
        return
    taken = sorted(set(reported) & {*summary, *later})
    if taken:
        raise PluginError(
            source.plugin,
            f"report returned {', '.join(map(repr, taken))}: "
            f"{'sections' if len(taken) > 1 else 'a section'} the run writes itself (a plugin's report may "
            "only add sections of its own)",
        )
    summary.update(reported)
