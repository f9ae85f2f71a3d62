"""``firmware-sim --avr``: serve the board firmware on simavr behind a pty, from firmware-sim's options.

The board options (units, rates, timeouts, battery) become the firmware's EEPROM configuration block;
the fault options the harness can reproduce become harness options. What the harness does not model
(a link stall, extra pack resistance, a dead ESC, battery capacity) is refused with a clear error
rather than silently ignored. With ``--world`` the firmware is not served from here: firmware-sim steps it
as the board of the world (:mod:`.stepped`), behind its own pty server.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from protocol.errors import ConfigError

from ..board.config import BoardConfig
from .harness import HarnessOptions, spawn_interactive
from .paths import FIRMWARE_ELF


def options_from_args(args: argparse.Namespace, config: BoardConfig) -> HarnessOptions:
    """The harness options for firmware-sim's command line (times relative to the harness's start)."""
    from ..cli import build_parser, parse_sag

    unsupported = (
        ("--stall", args.stall),
        ("--sag-ohms", args.sag_ohms),
        ("--dead-esc", args.dead_esc),
        ("--phone-gap", args.phone_gap),  # only with --world
        ("--capacity", args.capacity != build_parser().get_default("capacity")),  # no charge modelled
        ("--no-hold", args.no_hold),  # the harness always holds the pty open for a host that comes back
        ("--phone", args.phone != build_parser().get_default("phone")),  # only with --world
        ("--unit-spread", args.unit_spread is not None),  # the firmware's units are open-loop estimates
    )
    for flag, given in unsupported:
        if given:
            raise ConfigError("not available with --avr (the harness does not model it)", flag)
    sags = []
    for spec in args.sag:
        volts, at, ramp = parse_sag(spec)
        sags.append((volts, 0.0 if at is None else at, ramp, float("inf")))
    full = config.power.battery.cells * 4.2
    sags += [(full, t, 0.0, 0.3) for t in args.brownout_at]
    cells = config.power.battery.cells
    return HarnessOptions(
        elf=Path(args.avr) if args.avr else FIRMWARE_ELF,
        link=args.link,
        eeprom_file=Path(args.eeprom) if args.eeprom else None,
        battery_v=cells * _ocv_per_cell(config, args.soc),
        corrupt=args.corrupt,
        drop=args.drop,
        seed=args.seed,
        hang_at=tuple(args.hang_at),
        sags=tuple(sags),
        duration_s=args.duration,
    )


def _ocv_per_cell(config: BoardConfig, soc: float) -> float:
    """The open-circuit volts per cell of the configured LiPo at state of charge ``soc``."""
    curve = config.power.battery.ocv_curve
    for (s0, v0), (s1, v1) in zip(curve, curve[1:], strict=False):
        if soc <= s1:
            return v0 + (v1 - v0) * (min(max(soc, s0), s1) - s0) / (s1 - s0)
    return curve[-1][1]


def run(args: argparse.Namespace, config: BoardConfig) -> int:
    """Serve until interrupted (or --duration); the first stdout line is the pty path."""
    if args.fault_direction != "both" and (args.corrupt or args.drop):
        raise ConfigError("the harness damages both directions", "--fault-direction")
    return spawn_interactive(options_from_args(args, config), config, sys.stdout)
