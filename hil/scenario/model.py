"""The loaded scenario: everything a closed-loop run needs, as the parts' own parameter types."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hil.estimation.interface import Estimator, Site
from hil.estimation.registry import EstimatorChoice
from hil.vscmg import SpacecraftParams

from .config import LoopConfig, SlewScenario
from .phone import PhoneSpec

SPINUP_S = 2.0
"""s: what a run's rotors take to spin up and settle before the slew, on top of its warm-up (a planned
figure: :meth:`Scenario.planned_length_s`)."""


@dataclass(frozen=True)
class SlewTime:
    """The time a slew needs to be judged (s, from its start): ``trajectory_s`` to turn, then
    ``settle_s`` for the controller to settle (:meth:`Scenario.time_to_judge`)."""

    trajectory_s: float
    settle_s: float

    @property
    def total_s(self) -> float:
        return self.trajectory_s + self.settle_s

    def shortfall(self, duration_s: float) -> str | None:
        """Why a run of ``duration_s`` (s from the slew's start) is too short to judge its requirement,
        or None when it is long enough."""
        if duration_s >= self.total_s:
            return None
        return (
            f"the run's {duration_s:g} s is shorter than its slew needs to settle, {self.total_s:.1f} s "
            f"({self.trajectory_s:.1f} s to turn, then ~{self.settle_s:.1f} s to settle, 4/(ζ ω_n))"
        )


@dataclass(frozen=True)
class Scenario:
    """A loaded scenario. ``board_options`` and ``fault_options`` are firmware-sim's command-line options
    (name without dashes → value; a list for a repeatable option), so the same scenario drives the
    in-process emulator, a spawned firmware-sim and ``firmware-sim --world``. ``source`` is the TOML text
    as read (copied into every run directory). ``true_spacecraft``: the spacecraft the world flies when it
    differs from the nominal one the host's controller is designed for (None: the same)."""

    name: str
    description: str
    spacecraft: SpacecraftParams
    phone: PhoneSpec
    estimator: EstimatorChoice
    loop: LoopConfig
    slew: SlewScenario
    settle_deg: float = 0.5
    seed: int = 0
    board_options: Mapping[str, Any] = field(default_factory=dict)
    fault_options: Mapping[str, Any] = field(default_factory=dict)
    source: str = ""
    path: Path | None = None
    true_spacecraft: SpacecraftParams | None = None

    @property
    def world_spacecraft(self) -> SpacecraftParams:
        """The spacecraft the simulated world flies: ``true_spacecraft`` when a run disperses it (a Monte
        Carlo draw: the controller keeps the nominal ``spacecraft``), else the nominal one."""
        return self.spacecraft if self.true_spacecraft is None else self.true_spacecraft

    @property
    def n_units(self) -> int:
        return self.spacecraft.n_units

    def firmware_sim_options(self) -> list[tuple[str, str]]:
        """The board and fault options as (name, value) pairs in firmware-sim's spelling (a repeatable
        option once per value), plus the unit count: an emu:// or spawn:// query, or a command line."""
        pairs: list[tuple[str, str]] = [("units", str(self.n_units))]
        for options in (self.board_options, self.fault_options):
            for key, value in options.items():
                for v in value if isinstance(value, list) else [value]:
                    pairs.append((key, str(v)))
        return pairs

    def firmware_sim_argv(self) -> list[str]:
        """:meth:`firmware_sim_options` as command-line arguments."""
        # OPTION=VALUE: a value such as "-5:-1" is the option's, not another option for argparse
        return [f"--{key.replace('_', '-')}={value}" for key, value in self.firmware_sim_options()]

    def emulator_url(self, scheme: str = "emu") -> str:
        """``emu://?units=4&frame_rate=50&...`` (or ``spawn://firmware-sim?...``) for this scenario."""
        from urllib.parse import urlencode

        query = urlencode(self.firmware_sim_options())
        return f"emu://?{query}" if scheme == "emu" else f"spawn://firmware-sim?{query}"

    def estimator_site(self) -> Site:
        """Where the host's estimator runs: this scenario's phone's field (ENU), its fastest sensor's
        period (the merged steps'), the attitude measured from the first samples."""
        phone = self.phone
        fastest_hz = max(s.rate_hz for s in (phone.gyr, phone.acc, phone.mag))
        return Site.of_field(phone.field_enu_uT, 1.0 / fastest_hz)

    def make_estimator(self) -> Estimator:
        """A fresh estimator of this scenario's choice (``[estimator]``) for its phone."""
        return self.estimator.build(self.estimator_site())

    def with_board(self, board: str | None) -> Scenario:
        """A copy whose built-in emulator is ``board`` (``emu://?board=...``: ``emulator``, the Python
        board, or ``firmware``, the firmware ELF under simavr); None: as the scenario says."""
        if board is None:
            return self
        from hil.scenario.reader import check_firmware_board  # the reader builds this module's Scenario

        chosen = replace(self, board_options={**self.board_options, "board": board})
        check_firmware_board(chosen)  # a pack the firmware's ADC cannot read: named before anything starts
        return chosen

    def time_to_judge(self) -> SlewTime:
        """How long after its start this scenario's slew needs before its pointing requirement can be
        judged (:class:`SlewTime`): its rest-to-rest trajectory within ``max_rate`` and ``max_accel``
        (:meth:`hil.control.attitude.EigenaxisSlew.within_limits`, from the nominal start attitude; the host
        plans from its estimate, a rounding away), then the controller's settling, 4 / (ζ ω_n), the 2 %
        settling time of its second-order error dynamics. A run shorter than that ends before the slew
        could settle: its miss is the duration's, not the system's."""
        from hil.control.attitude import EigenaxisSlew  # the controller's module; imported when asked

        slew = self.slew
        trajectory = EigenaxisSlew.within_limits(slew.R0, slew.R_target, slew.max_rate, slew.max_accel)
        gains = self.loop.gains
        return SlewTime(trajectory.duration_s, 4.0 / (gains.damping * gains.natural_frequency))

    def planned_length_s(self) -> float:
        """The run's length as planned (s of its clock from its start): the warm-up (``loop.warmup_s``),
        the rotors' spin-up and settling (:data:`SPINUP_S`) and the duration after the slew starts. A
        fault during the warm-up, or a slow spin-up, makes a run longer; none makes it shorter."""
        return self.loop.warmup_s + SPINUP_S + self.slew.duration_s

    def with_changes(self, **changes: Any) -> Scenario:
        """A copy with fields replaced (Monte Carlo dispersions, ``--duration``)."""
        return replace(self, **changes)
