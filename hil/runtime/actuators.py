"""The host's watch on the actuators: whether each rotor and gimbal does what it is told, from the board's
telemetry and the host's own setpoints, on the control tick. What it finds goes into the fault journal
(as notes: the host stays in control and goes on with the array it has) and ``events.jsonl``:

================================  ==================================================================
record                            when
================================  ==================================================================
``esc_dead``                      the board's DEAD_ESC flag appears (its detector: an output commanded
                                  well above rest shows no response; its Log names the channel)
``rotor_not_following`` (unit)    the rotor's speed setpoint held at its lead limit above the measured
                                  speed (:class:`hil.control.motor_loops.SetpointGenerator`) for
                                  :data:`LAG_S`: a dead ESC, a motor that lost its supply. The board's
                                  detector cannot see it while the host steers: the setpoint, kept
                                  within its lead of the measured speed, follows the rotor down
``gimbal_not_following`` (unit)   asked, on average over the last :data:`LAG_S` in RATE mode, for at
                                  least :data:`GIMBAL_MIN_RATE` one way, and turning that way at less
                                  than half of it, for :data:`LAG_S` more: a dead servo (the board's
                                  detector looks only above 0.1 rad/s, more than a slew at this scale
                                  asks for). Averaged, not tick by tick: a stuck gimbal asked for a few
                                  mrad/s while the others hold the attitude (a campaign's finding: 4.5
                                  mrad/s for 14 s, the pointing off 0.9°, never reported) is seen
                                  through the rate's telemetry noise
``power_shed`` (state)            the board's power manager says SHED (it stopped the rotors to save
                                  the battery) or BROWN_OUT: the array has no rotor authority until it
                                  says otherwise (said again at each new episode). Before, only the
                                  rotors' not following was said, never why
``rotor_overspeed`` (unit)        the rotor measured faster than :data:`OVERSPEED` × the spacecraft's
                                  fastest rotor speed, on any live telemetry (commanded or not): no
                                  setpoint asks for it, so the rotor runs away (an ESC out of its
                                  mode, a speed map far off) or the board's speed reading is wrong —
                                  either way the host steers on a speed it should not trust. Before,
                                  a rotor read at 4× its limit was shown live and steered on, no
                                  record
================================  ==================================================================

Each unit's rotor and gimbal is reported once per run.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Sequence

from hil.runtime.faults import FaultJournal
from hil.runtime.runlog import EventLog
from protocol.messages import ActuatorSetpoint, FaultFlag, GimbalMode, PowerState, UnitState

logger = logging.getLogger(__name__)

LAG_S = 1.0
"""s: an actuator off its setpoint this long does not follow it."""
OVERSPEED = 1.1
"""A rotor measured faster than this × the spacecraft's fastest rotor speed is ``rotor_overspeed``: the
setpoints never ask for more than the fastest speed, and a rotor overshoots it by a few percent at most."""
GIMBAL_MIN_RATE = 0.002
"""rad/s: a gimbal asked less than this on average over :data:`LAG_S` is not asked enough to tell (a
healthy gimbal's measured rate scatters by ~0.5 mrad/s a frame; averaged over a second, far less)."""


class RateWindow:
    """The last ``span`` seconds of a gimbal's asked and measured rates (rad/s), with their running sums:
    the means cost the same whatever the window holds (it is on the control tick, for every unit)."""

    def __init__(self, span: float) -> None:
        self.span = span
        self._samples: deque[tuple[float, float, float]] = deque()
        self._asked = self._turned = 0.0

    def clear(self) -> None:
        self._samples.clear()
        self._asked = self._turned = 0.0

    def append(self, t: float, asked: float, turned: float) -> None:
        """Add the tick at ``t`` (s); forget those older than ``span``."""
        self._samples.append((t, asked, turned))
        self._asked += asked
        self._turned += turned
        while self._samples[0][0] < t - self.span:
            _, old_asked, old_turned = self._samples.popleft()
            self._asked -= old_asked
            self._turned -= old_turned

    @property
    def full(self) -> bool:
        """Whether it spans (nearly) ``span``: a mean over less says too little."""
        return self._samples[-1][0] - self._samples[0][0] >= 0.9 * self.span

    def means(self) -> tuple[float, float]:
        """The mean asked and measured rates (rad/s) over the window."""
        n = len(self._samples)
        return self._asked / n, self._turned / n


class ActuatorWatch:
    """See the module docstring. ``n`` units; ``max_lead`` (rad/s) the setpoint generator's bound on how
    far a rotor's speed setpoint may run ahead of its measured speed; ``max_speed`` (rad/s) the spacecraft's
    fastest rotor speed."""

    def __init__(
        self, n: int, journal: FaultJournal, events: EventLog, max_lead: float, max_speed: float
    ) -> None:
        self.journal = journal
        self.events = events
        self.lead = 0.9 * max_lead
        self.overspeed = OVERSPEED * max_speed
        self.esc_dead = False  # the board's DEAD_ESC flag as last seen
        self.shed = False  # the board's power state was SHED or worse, as last seen
        self._since: dict[tuple[str, int], float] = {}  # (actuator, unit) → off its setpoint since
        self._noted: set[tuple[str, int]] = set()
        self._gimbal = [RateWindow(LAG_S) for _ in range(n)]  # each gimbal's, in RATE mode
        self._keys = [(("rotor", i), ("gimbal", i)) for i in range(n)]  # each unit's keys of _since

    def board_flags(self, t: float, faults: int, power: int = PowerState.NORMAL) -> None:
        """The board's fault flags and power state of a live telemetry at ``t``: its dead-ESC report when it
        appears, and each episode of its power manager shedding the rotors (SHED, BROWN_OUT)."""
        shed = power >= PowerState.SHED
        if shed and not self.shed:
            state = PowerState(power).name
            self.journal.note(t, "power_shed", state=state)
            self.events.write(t, "power_shed", state=state)
            logger.warning("the board's power manager says %s at t=%.3f s: the rotors are stopped", state, t)
        self.shed = shed
        dead = bool(faults & FaultFlag.DEAD_ESC)
        if dead and not self.esc_dead:
            self.journal.note(t, "esc_dead")
            self.events.write(t, "esc_dead")
            logger.warning("the board reports a dead ESC at t=%.3f s (its log names the channel)", t)
        self.esc_dead = dead

    def rotor_speeds(self, t: float, rotor: Sequence[float]) -> None:
        """The rotor speeds ``rotor`` (n floats, rad/s) of a live telemetry at ``t``: a rotor faster than
        :attr:`overspeed` either way is reported, once per unit and run."""
        limit = self.overspeed
        if max(rotor) <= limit and min(rotor) >= -limit:
            return  # the usual case: two comparisons a tick
        for unit, speed in enumerate(rotor):
            key = ("overspeed", unit)
            if abs(speed) > limit and key not in self._noted:
                self._noted.add(key)
                self.journal.note(t, "rotor_overspeed", unit=unit, measured=speed, limit=limit)
                self.events.write(t, "rotor_overspeed", unit=unit, measured=speed, limit=limit)
                logger.warning(
                    "unit %d's rotor measured at %.1f rad/s at t=%.3f s, beyond %.1f rad/s: it runs away, "
                    "or the board's reading of it is wrong",
                    unit,
                    speed,
                    t,
                    limit,
                )

    def following(
        self, t: float, rotor: Sequence[float], units: Sequence[UnitState], command: ActuatorSetpoint
    ) -> None:
        """The tick's setpoint ``command`` (the steering's, sent at ``t``) against the measured rotor
        speeds ``rotor`` (n floats, or an (n,) array) rad/s and the telemetry's ``units``.

        Every control tick, for every unit: a unit that follows (the usual case) costs two comparisons
        and, only while something is off its setpoint, a look in the record of what is
        (:meth:`following_reference` is the check spelt out, the oracle of a test)."""
        rate_mode = command.gimbal_mode is GimbalMode.RATE
        lead, since, keys = self.lead, self._since, self._keys
        for i, (sp, state) in enumerate(zip(command.units, units, strict=True)):
            speed = float(rotor[i])
            rotor_key, gimbal_key = keys[i]
            if sp.rotor_speed - speed >= lead:
                self._off(t, rotor_key, speed)
            elif since:
                since.pop(rotor_key, None)
            if self._gimbal_stuck(i, t, rate_mode, sp.gimbal, state.gimbal_rate):
                self._off(t, gimbal_key, float(state.gimbal_rate))
            elif since:
                since.pop(gimbal_key, None)

    def following_reference(
        self, t: float, rotor: Sequence[float], units: Sequence[UnitState], command: ActuatorSetpoint
    ) -> None:
        """:meth:`following` one check at a time (the form it replaced, kept as its oracle)."""
        rate_mode = command.gimbal_mode is GimbalMode.RATE
        for i, (sp, state) in enumerate(zip(command.units, units, strict=True)):
            speed = float(rotor[i])
            self._check(t, "rotor", i, sp.rotor_speed - speed >= self.lead, speed)
            stuck = self._gimbal_stuck(i, t, rate_mode, sp.gimbal, state.gimbal_rate)
            self._check(t, "gimbal", i, stuck, float(state.gimbal_rate))

    def _gimbal_stuck(self, unit: int, t: float, rate_mode: bool, asked: float, measured: float) -> bool:
        """Whether gimbal ``unit``, asked ``asked`` and turning at ``measured`` (rad/s) at ``t``, was over
        the last :data:`LAG_S` asked on average for at least :data:`GIMBAL_MIN_RATE` one way and turned
        that way at less than half of it. Outside RATE mode the window starts again."""
        window = self._gimbal[unit]
        if not rate_mode:
            window.clear()
            return False
        window.append(t, asked, measured)
        if not window.full:
            return False
        mean_asked, mean_turned = window.means()
        if abs(mean_asked) < GIMBAL_MIN_RATE:
            return False
        return mean_turned * math.copysign(1.0, mean_asked) < 0.5 * abs(mean_asked)

    def _check(self, t: float, actuator: str, unit: int, off: bool, measured: float) -> None:
        key = (actuator, unit)
        if not off:
            self._since.pop(key, None)
            return
        self._off(t, key, measured)

    def _off(self, t: float, key: tuple[str, int], measured: float) -> None:
        """The actuator ``key`` (actuator, unit) is off its setpoint at ``t``, measured at ``measured``:
        reported once it has been for :data:`LAG_S`."""
        actuator, unit = key
        since = self._since.setdefault(key, t)
        if t - since >= LAG_S and key not in self._noted:
            self._noted.add(key)
            kind = f"{actuator}_not_following"
            self.journal.note(t, kind, unit=unit, measured=measured)
            self.events.write(t, kind, unit=unit, measured=measured)
            logger.warning("unit %d's %s does not follow its setpoint at t=%.3f s", unit, actuator, t)
