"""The world's models, pure math (no I/O, no board): the spacecraft plant stepped in time (:mod:`.plant`, the
numpy reference; :mod:`.compiled` with its kernels :mod:`.kernels`, the same step compiled for one run), the
motor drives (:mod:`.servos`, the numpy reference; :mod:`.drives`, the compiled law) and the simulated phone
(:mod:`.phone`). The equations they integrate, and the state they step, are the host's too:
:mod:`hil.vscmg` (docs/dynamics.md derives them)."""

from .compiled import CompiledPlant
from .drives import Drive
from .phone import BodyPhone, Trajectory, paper_testbed_rate, simulate
from .plant import GravityGradient, Plant, TorqueLaw, Torques
from .servos import ServoModel

__all__ = [
    "BodyPhone",
    "CompiledPlant",
    "Drive",
    "GravityGradient",
    "Plant",
    "ServoModel",
    "TorqueLaw",
    "Torques",
    "Trajectory",
    "paper_testbed_rate",
    "simulate",
]
