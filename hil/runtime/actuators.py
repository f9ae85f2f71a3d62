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
``gimbal_not_following`` (unit)   asked for at least :data:`GIMBAL_MIN_RATE` in RATE mode and turning
                                  at less than half of it for :data:`LAG_S`: a dead servo (the board's
                                  detector looks only above 0.1 rad/s, more than a slew at this scale
                                  asks for)
================================  ==================================================================

Each unit's rotor and gimbal is reported once per run.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from hil.runtime.faults import FaultJournal
from hil.runtime.runlog import EventLog
from protocol.messages import ActuatorSetpoint, FaultFlag, GimbalMode, UnitState

logger = logging.getLogger(__name__)

LAG_S = 1.0
"""s: an actuator off its setpoint this long does not follow it."""
GIMBAL_MIN_RATE = 0.005
"""rad/s: a gimbal asked less than this is not asked enough to tell."""


class ActuatorWatch:
    """See the module docstring. ``n`` units; ``max_lead`` (rad/s) the setpoint generator's bound on how
    far a rotor's speed setpoint may run ahead of its measured speed."""

    def __init__(self, n: int, journal: FaultJournal, events: EventLog, max_lead: float) -> None:
        self.journal = journal
        self.events = events
        self.lead = 0.9 * max_lead
        self.esc_dead = False  # the board's DEAD_ESC flag as last seen
        self._since: dict[tuple[str, int], float] = {}  # (actuator, unit) → off its setpoint since
        self._noted: set[tuple[str, int]] = set()

    def board_flags(self, t: float, faults: int) -> None:
        """The board's fault flags of a live telemetry at ``t``: its dead-ESC report when it appears."""
        dead = bool(faults & FaultFlag.DEAD_ESC)
        if dead and not self.esc_dead:
            self.journal.note(t, "esc_dead")
            self.events.write(t, "esc_dead")
            logger.warning("the board reports a dead ESC at t=%.3f s (its log names the channel)", t)
        self.esc_dead = dead

    def following(
        self, t: float, rotor: NDArray[np.float64], units: Sequence[UnitState], command: ActuatorSetpoint
    ) -> None:
        """The tick's setpoint ``command`` (the steering's, sent at ``t``) against the measured rotor
        speeds ``rotor`` (n,) rad/s and the telemetry's ``units``."""
        rate_mode = command.gimbal_mode is GimbalMode.RATE
        for i, (sp, state) in enumerate(zip(command.units, units, strict=True)):
            self._check(t, "rotor", i, sp.rotor_speed - rotor[i] >= self.lead, float(rotor[i]))
            want = sp.gimbal
            stuck = (
                rate_mode and abs(want) >= GIMBAL_MIN_RATE and abs(state.gimbal_rate - want) > 0.5 * abs(want)
            )
            self._check(t, "gimbal", i, stuck, float(state.gimbal_rate))

    def _check(self, t: float, actuator: str, unit: int, off: bool, measured: float) -> None:
        key = (actuator, unit)
        if not off:
            self._since.pop(key, None)
            return
        since = self._since.setdefault(key, t)
        if t - since >= LAG_S and key not in self._noted:
            self._noted.add(key)
            kind = f"{actuator}_not_following"
            self.journal.note(t, kind, unit=unit, measured=measured)
            self.events.write(t, kind, unit=unit, measured=measured)
            logger.warning("unit %d's %s does not follow its setpoint at t=%.3f s", unit, actuator, t)
