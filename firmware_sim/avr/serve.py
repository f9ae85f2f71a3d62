"""``firmware-sim --avr``: the board firmware on simavr behind a pty, served by the harness itself, paced
to real time — a :class:`HarnessServer`, read like every other server (:class:`..servers.base.BoardServer`:
the same statistics, host presence and status lines).

The board options (units, rates, timeouts, battery) become the firmware's EEPROM configuration block;
the fault options the harness can reproduce become harness options. What the harness does not model
(a link stall, extra pack resistance, a dead ESC, battery capacity) is refused with a clear error
rather than silently ignored. With ``--world`` or ``--can`` the firmware is not served from here:
firmware-sim steps it (:mod:`.stepped`) behind its own pty or CAN server.

The harness serves the pty in C (its UART bridge, paced in its own loop); this server polls its control
pipe every :data:`POLL_S` for the bridge's counters (``stats``), its time (``now``) and the firmware's
protocol state (its RAM, ``mem``), so ``firmware-sim``'s status lines and final statistics read as for
the Python board. A harness that ends without being asked to raises :class:`.harness.HarnessDied` from
:meth:`HarnessServer.serve` (firmware-sim: one line, exit status 3), its ``--link`` symlink removed if it
still points at its pty.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING

from protocol.errors import ConfigError, LinkTimeout
from protocol.messages import BoardState

from ..board.config import BoardConfig
from ..servers.base import BoardServer, HostPresence
from .build import ensure_built
from .eeprom import check_hardware
from .harness import F_CPU, HarnessDied, HarnessOptions, HarnessProcess, eeprom_for, remove_link
from .paths import FIRMWARE_ELF

if TYPE_CHECKING:
    from .stepped import UsbState

logger = logging.getLogger(__name__)

POLL_S = 0.05
"""How often the server reads the harness's counters, time and state (s): the host's presence and the
board's state changes are seen within this (well inside HOST_SILENCE_S and a human's notice). A state
that lasts less (a handshake's DISARMED followed at once by an Arm) may pass unseen: the C bridge serves
the pty between two looks, unlike the Python servers, which note every change as the board runs."""


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
        usb=args.usb,
    )


def _ocv_per_cell(config: BoardConfig, soc: float) -> float:
    """The open-circuit volts per cell of the configured LiPo at state of charge ``soc``."""
    curve = config.power.battery.ocv_curve
    for (s0, v0), (s1, v1) in zip(curve, curve[1:], strict=False):
        if soc <= s1:
            return v0 + (v1 - v0) * (min(max(soc, s0), s1) - s0) / (s1 - s0)
    return curve[-1][1]


class HarnessServer(BoardServer):
    """The firmware on simavr serving a pty (``options``; its configuration block from ``config``): the
    harness's own UART bridge, watched through its control pipe. See the module docstring."""

    def __init__(self, options: HarnessOptions, config: BoardConfig) -> None:
        from .stepped import board_field_address

        check_hardware(config)
        ensure_built()
        self.config = config
        self.options = options
        self._files = contextlib.ExitStack()
        eeprom_path, fds = self._files.enter_context(eeprom_for(options, config))
        self._state_at = board_field_address(options.elf, "state")
        try:
            self.process = HarnessProcess(options.arguments(eeprom_path, None, control=True), fds)
        except BaseException:
            self._files.close()
            raise
        self.path = self.process.port
        super().__init__(f"firmware on simavr at {self.path}")
        self.presence = HostPresence(self.stats)
        self._now = 0.0
        self._unanswered_since: float | None = None
        """When (``time.monotonic``, s) the harness last began not answering a look; None: it answers."""

    # ------------------------------------------------------------------ BoardServer
    def board_time(self) -> float:
        return self._now

    def look(self) -> None:
        """Read the harness's counters, time and the firmware's state once (see :data:`POLL_S`). A harness
        that runs but does not answer (stopped by SIGSTOP or a debugger, or not run by a machine that is
        too busy) is a board that does not run for that while, not a dead one: said once, watched on,
        and said again when it answers (before, the first unanswered look ended firmware-sim with a
        ``LinkTimeout`` traceback, status 1, and took the board down with it)."""
        names = ("bytes_in", "bytes_out", "dropped_out", "corrupted", "dropped", "lag_resets")
        asked = time.monotonic()  # the pause is timed from the first look that went unanswered
        try:
            now = int(self.process.command("now")[0]) / F_CPU  # before the counters: HostPresence.tick
            counts = dict(
                zip((*names, "frames_in", "frames_out"), map(int, self.process.command("stats")), strict=True)
            )
            state = bytes.fromhex(self.process.command(f"mem {self._state_at} 1")[0])[0]
        except LinkTimeout as exc:  # HarnessDied (it ended) is a LinkError, not a timeout: it goes on up
            if self._unanswered_since is None:
                self._unanswered_since = asked
                logger.warning(
                    "avr-harness (pid %d) runs but does not answer (stopped, or not given the CPU): the "
                    "board on %s is not running; still watching (%s)",
                    self.process.pid,
                    self.path,
                    exc,
                )
            return
        if self._unanswered_since is not None:
            logger.warning(
                "avr-harness (pid %d) answers again after %.1f s: the board on %s runs on",
                self.process.pid,
                time.monotonic() - self._unanswered_since,
                self.path,
            )
            self._unanswered_since = None
        stats = self.stats
        if counts["bytes_in"] > stats.bytes_in:
            self.presence.heard(now)
        else:
            self.presence.tick(now)
        stats.bytes_in, stats.bytes_out = counts["bytes_in"], counts["bytes_out"]
        stats.frames_in, stats.frames_out = counts["frames_in"], counts["frames_out"]
        stats.dropped_out = counts["dropped_out"]
        self._now = now
        with contextlib.suppress(ValueError):  # a byte that is no state: the firmware mid-reset
            self.note_state(now, BoardState(state))

    def serve(self, duration: float | None = None) -> None:
        end = None if duration is None else self._now + duration
        while not self.stopping():
            self.look()
            self.stats.loops += 1
            if end is not None and self._now >= end:
                return
            self._stop.wait(POLL_S)

    def usb_state(self) -> UsbState:
        """The phone on the board's USB host port as the harness sees it now (``usbstate``; ``--usb``)."""
        from .stepped import UsbState

        return UsbState.parse(self.process.command("usbstate"))

    def _release(self) -> None:
        process = self.process
        process.close()
        self._files.close()
        if process.returncode not in (0, None) and self.options.link:
            remove_link(self.options.link, self.path)  # it did not stop cleanly: the link is still there


def server_from_args(args: argparse.Namespace, config: BoardConfig) -> HarnessServer:
    """The harness server firmware-sim's options describe (its pty path printed by the caller)."""
    if args.fault_direction != "both" and (args.corrupt or args.drop):
        raise ConfigError("the harness damages both directions", "--fault-direction")
    return HarnessServer(options_from_args(args, config), config)


__all__ = ["POLL_S", "HarnessDied", "HarnessServer", "options_from_args", "server_from_args"]
