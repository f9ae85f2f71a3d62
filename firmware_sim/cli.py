"""``firmware-sim``: the emulated ADK board on a real pseudo-terminal, in real time, until interrupted.

The first line on stdout is the pty's path and nothing else (scripts read it); everything else goes to
stderr. SIGINT, SIGTERM and SIGHUP (its terminal closed) end it cleanly at any moment, start-up included
(the symlink is removed, exit status 0; :class:`StopOnSignals`); a bad option is exit status 2; with
``--avr``, a harness that dies under it is one error line and exit status 3.
"""

from __future__ import annotations

import argparse
import logging
import os
import random
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from types import FrameType
from typing import TYPE_CHECKING, Any

from hil.cli._parser import ArgumentParser
from hil.cli.run import seconds
from hil.scenario.fault_specs import (
    MAX_SAG_OHMS,
    parse_dead_esc,
    parse_jump,
    parse_noise,
    parse_sag,
    parse_spoof,
    parse_stall,
    parse_time,
)
from protocol.errors import ConfigError, HilError, LinkError

DEFAULT_UNITS = 4
"""VSCMG units of a board without ``--units`` or ``--world``."""
MAX_SEED = 10**18
"""The largest ``--seed``: the firmware harness's own bound (``firmware/harness/main.c``), so that one seed
seeds the Python board's fault injector and the firmware's link noise alike."""


def seed(text: str) -> int:
    """``--seed``: an integer 0..:data:`MAX_SEED`. A negative one seeded the Python board as its absolute
    value (``random.Random(-1)`` is ``Random(1)``: two seeds, one run) and the harness refused it; anything
    else is argparse's error naming the option (status 2)."""
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be an integer in 0..{MAX_SEED}, got {text[:40]!r}")
    return value


if TYPE_CHECKING:
    from hil.scenario.model import Scenario

    from .avr.harness import HarnessDied

EPILOG = """\
examples:
  firmware-sim                                  serve 4 units on a new pty, print its path
  firmware-sim --link /tmp/vscmg-board          ... and keep /tmp/vscmg-board pointing at it
  hil run --port /tmp/vscmg-board               (in another terminal) drive it
  firmware-sim --units 3 --frame-rate 400 --telemetry-rate 100
  firmware-sim --link-timeout 0.5 --mcu-watchdog 1.0
  firmware-sim --corrupt 0.01 --drop 0.001      damage 1% / lose 0.1% of the bytes, both ways
  firmware-sim --stall 5:2                      the link carries nothing from t=5 s for 2 s
  firmware-sim --hang-at 5                      main loop hangs at t=5 s: watchdog reset follows
  firmware-sim --sag 6@10/5                     battery loses 6 V from t=10 s, ramped over 5 s:
                                                warn -> limit -> shed (load shedding holds the rail)
  firmware-sim --sag 9@10/5                     ... 9 V: the UBEC drops out, brown-out reset
  firmware-sim --brownout-at 8                  a short collapse of the pack at t=8 s
  firmware-sim --dead-esc 1@3                   the ESC on channel 1 (rotor 0) dies at t=3 s
  firmware-sim --unit-spread 7 --esc-supply-switch
                                                a bench to calibrate: units unlike their calibration,
                                                ESCs at factory endpoints (hil calibrate unit --port)
  firmware-sim --duration 30 -v                 stop after 30 s, log state changes
  firmware-sim --avr                            the real firmware (firmware/) on simavr's ATmega2560
  firmware-sim --avr --eeprom board.eep         ... keeping its EEPROM (uploaded calibrations) in a file
  firmware-sim --avr --usb                      ... its link the phone on its USB host port (Android Open
                                                Accessory through the emulated MAX3421E), not UART0
  firmware-sim --world cubesat-1u --link /tmp/vscmg
                                                the board drives a simulated spacecraft (a hil scenario);
                                                its phone streams to udp://127.0.0.1:8123 (hil run --port)
  firmware-sim --avr --world cubesat-1u --link /tmp/vscmg
                                                ... the real firmware under simavr drives it, in real time
  firmware-sim --avr --usb --world cubesat-1u --usb-detach 25:1
                                                ... the host as the phone's accessory app over USB; the
                                                phone pulled off the board at t=25 s for 1 s
  firmware-sim --can udp_multicast/239.74.163.2?port=43113
                                                serve on a CAN bus instead (prints the host's URL)
  firmware-sim --avr --can udp_multicast/239.74.163.2?port=43113
                                                ... the real firmware, its UART bridged onto the bus
  hil run --port can://udp_multicast/239.74.163.2?port=43113   (in another terminal) drive it

Times are seconds since start on the board's clock. Channels: gimbal 0, rotor 0, gimbal 1, rotor 1, ...
"""

EXIT_HARNESS_DIED = 3
"""The exit status of ``firmware-sim --avr`` when its ``avr-harness`` ended without being asked to (killed,
crashed, exited): the board it served is gone (docs/firmware_sim.md, "Lifetimes")."""


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(
        prog="firmware-sim",
        description="Emulated ADK board (VSCMG actuators) behind a real pseudo-terminal.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "-v", "--verbose", action="count", default=0, help="debug log (default: state changes, faults)"
    )
    p.add_argument("--link", metavar="PATH", help="keep a symlink at PATH pointing at the pty")
    p.add_argument(
        "--duration", type=seconds, metavar="S", help="stop after S seconds (default: run until ^C)"
    )
    p.add_argument(
        "--avr",
        nargs="?",
        const="",
        metavar="ELF",
        help="run the board firmware on simavr instead of the emulator (default: firmware/build/*.elf)",
    )
    p.add_argument(
        "--eeprom",
        metavar="FILE",
        help="with --avr: the board's EEPROM, loaded and saved back (a stored configuration wins over the "
        "board options)",
    )
    p.add_argument(
        "--usb",
        action="store_true",
        help="with --avr: the pty is an Android phone's accessory app on the board's USB host port (the "
        "harness's MAX3421E model, the firmware's AOA link) instead of UART0; a new EEPROM says link = usb "
        "(with --world too; not with --can)",
    )
    p.add_argument(
        "--can",
        metavar="INTERFACE/CHANNEL[?OPTIONS]",
        help="serve on a python-can bus instead of a pty (options as in can:// URLs: node, fd, port, ...)",
    )
    p.add_argument(
        "--world",
        metavar="SCENARIO",
        help="close the loop: the pulses drive this hil scenario's spacecraft (name or .toml; sets --units)",
    )
    p.add_argument(
        "--phone",
        default="udp://127.0.0.1:8123",
        metavar="URL",
        help="with --world: where the simulated phone streams: udp://HOST:PORT as SensaGram does (default "
        "%(default)s), http://HOST:PORT/ as Sensor Logger's HTTP Push",
    )
    p.add_argument(
        "--no-hold",
        action="store_true",
        help="do not hold the pty's slave side open (the master then sees EIO while no host is on)",
    )
    b = p.add_argument_group("board")
    b.add_argument(
        "--units",
        type=int,
        default=None,
        metavar="N",
        help=f"VSCMG units, 1..8 (default {DEFAULT_UNITS}; with --world the scenario's)",
    )
    b.add_argument(
        "--frame-rate", type=float, default=50.0, metavar="HZ", help="pulse frame rate, 50..490 Hz"
    )
    b.add_argument(
        "--telemetry-rate", type=float, default=20.0, metavar="HZ", help="telemetry rate (default 20)"
    )
    b.add_argument("--heartbeat-rate", type=float, default=5.0, metavar="HZ", help="board heartbeat rate")
    b.add_argument(
        "--link-timeout", type=float, default=0.25, metavar="S", help="link watchdog (default 0.25)"
    )
    b.add_argument("--mcu-watchdog", type=float, default=0.5, metavar="S", help="MCU watchdog (default 0.5)")
    b.add_argument(
        "--rotor-safe-us",
        type=int,
        default=1000,
        metavar="US",
        help="rotor pulse when disarmed / failsafe (default 1000)",
    )
    b.add_argument("--ppm", action="store_true", help="also generate a PPM-sum train of the first 8 channels")
    b.add_argument("--cells", type=int, default=3, metavar="N", help="battery cells in series (default 3)")
    b.add_argument(
        "--capacity", type=float, default=1000.0, metavar="MAH", help="battery capacity (default 1000)"
    )
    b.add_argument("--soc", type=float, default=1.0, metavar="F", help="initial state of charge 0..1")
    b.add_argument(
        "--seed",
        type=seed,
        default=0,
        help=f"seed of the fault injector's random numbers (0..{MAX_SEED:.0e})",
    )
    b.add_argument(
        "--esc-supply-switch",
        action="store_true",
        help="the board can cut the ESCs' supply (ESC endpoint programming power-cycles the ESC itself; "
        "without it the board asks the operator)",
    )
    b.add_argument(
        "--unit-spread",
        type=int,
        metavar="SEED",
        help="bench units: each unit's motor and servo drawn around the stated models with this seed, its "
        "ESC at factory endpoints until programmed (default: ideal units, exactly their calibration)",
    )
    f = p.add_argument_group("fault injection")
    f.add_argument("--corrupt", type=float, default=0.0, metavar="P", help="per-byte corruption probability")
    f.add_argument("--drop", type=float, default=0.0, metavar="P", help="per-byte loss probability")
    f.add_argument(
        "--fault-direction",
        choices=("rx", "tx", "both"),
        default="both",
        help="which way --corrupt/--drop act (rx: host to board)",
    )
    f.add_argument(
        "--stall", action="append", default=[], metavar="AT:DURATION", help="link stall (repeatable)"
    )
    f.add_argument(
        "--hang-at", action="append", type=float, default=[], metavar="T", help="MCU hang (repeatable)"
    )
    f.add_argument(
        "--sag", action="append", default=[], metavar="VOLTS[@AT[/RAMP]]", help="battery voltage sag"
    )
    f.add_argument(
        "--sag-ohms",
        action="append",
        default=[],
        metavar="OHMS[@AT[/RAMP]]",
        help="extra battery internal resistance",
    )
    f.add_argument(
        "--brownout-at",
        action="append",
        type=float,
        default=[],
        metavar="T",
        help="collapse the battery for 0.3 s at T: brown-out reset",
    )
    f.add_argument("--dead-esc", action="append", default=[], metavar="CH[@AT]", help="dead ESC on a channel")
    f.add_argument(
        "--phone-gap",
        action="append",
        default=[],
        metavar="AT:DURATION",
        help="with a world: its phone sends nothing for DURATION s from AT (repeatable)",
    )
    f.add_argument(
        "--unplug",
        action="append",
        default=[],
        metavar="AT:DURATION",
        help="the USB cable pulled for DURATION s from AT: the MCU unpowered, then a power-on boot "
        "(in process, the port vanishes meanwhile; repeatable)",
    )
    f.add_argument(
        "--usb-detach",
        action="append",
        default=[],
        metavar="AT:DURATION",
        help="with --avr --usb --world: the phone pulled off the board's USB host port at AT for DURATION s, "
        "then plugged back in its normal mode (the firmware enumerates and switches it again; repeatable)",
    )
    f.add_argument(
        "--noise",
        action="append",
        default=[],
        metavar="AT:DURATION:P",
        help="byte corruption at probability P, both ways, for DURATION s from AT (repeatable)",
    )
    f.add_argument(
        "--phone-jump",
        action="append",
        default=[],
        metavar="AT:OFFSET",
        help="with a world: from AT on its phone stamps samples OFFSET s later (negative: earlier)",
    )
    f.add_argument(
        "--phone-spoof",
        action="append",
        default=[],
        metavar="AT:KIND",
        help="with a world: at AT its phone sends hostile readings of KIND (huge, nan, saturated, future, "
        "past, duplicate, burst; repeatable)",
    )
    return p


OPTION_OF_SETTING: dict[str, str] = {
    "BoardConfig.n_units": "--units",
    "BoardConfig.frame_rate_hz": "--frame-rate",
    "BoardConfig.telemetry_rate_hz": "--telemetry-rate",
    "BoardConfig.heartbeat_rate_hz": "--heartbeat-rate",
    "BoardConfig.link_timeout_s": "--link-timeout",
    "BoardConfig.mcu_watchdog_s": "--mcu-watchdog",
    "BoardConfig.rotor_safe_us": "--rotor-safe-us",
    "BoardConfig.seed": "--seed",
    "BoardConfig.unit_spread_seed": "--unit-spread",
    "BoardConfig.power.battery.cells": "--cells",
    "BoardConfig.power.battery.capacity_mah": "--capacity",
    "BoardConfig.power.battery.initial_soc": "--soc",
    "faults.link.corrupt": "--corrupt",
    "faults.link.drop": "--drop",
    "faults.link.direction": "--fault-direction",
    "faults.phone_spoof": "--phone-spoof",
}
"""The board's and its fault injector's settings (a :class:`ConfigError`'s ``where``) that an option sets,
and that option: a refused value is told by the option the user typed (``--corrupt: 1.5 is not a
probability``), not by a field of the code (``faults.link.corrupt``) the user never saw."""


@contextmanager
def _named_by_option() -> Iterator[None]:
    """Re-raise a :class:`ConfigError` about a setting an option sets (:data:`OPTION_OF_SETTING`) as one
    naming that option; any other passes unchanged."""
    try:
        yield
    except ConfigError as exc:
        option = OPTION_OF_SETTING.get(exc.where)
        if option is None:
            raise
        raise ConfigError(exc.detail, option) from exc


def board_config(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """The board configuration the options describe, checked here — before the board, its firmware's
    EEPROM or a world is made of it — so that a value it refuses is an error naming the option
    (:data:`OPTION_OF_SETTING`)."""
    with _named_by_option():
        cfg = _board_config(args)
        cfg.validate()
    return cfg


def _board_config(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from dataclasses import replace

    from .board.config import BatteryParams, BoardConfig, PowerConfig

    return BoardConfig(
        n_units=DEFAULT_UNITS if args.units is None else args.units,
        frame_rate_hz=args.frame_rate,
        telemetry_rate_hz=args.telemetry_rate,
        heartbeat_rate_hz=args.heartbeat_rate,
        link_timeout_s=args.link_timeout,
        mcu_watchdog_s=args.mcu_watchdog,
        rotor_safe_us=args.rotor_safe_us,
        ppm=args.ppm,
        seed=args.seed,
        esc_supply_switch=args.esc_supply_switch,
        unit_spread_seed=args.unit_spread,
        power=PowerConfig(
            battery=replace(
                BatteryParams(), cells=args.cells, capacity_mah=args.capacity, initial_soc=args.soc
            )
        ),
    )


def make_board(  # type: ignore[no-untyped-def]
    args: argparse.Namespace, clock: object | None = None, boot_ids: random.Random | None = None
):
    """The board the options describe, faults scheduled (times relative to the clock's start); its boot
    ids drawn from ``boot_ids`` (default: from ``--seed``, see :class:`~firmware_sim.board.Board`)."""
    from hil.timing.clock import WallClock

    from .board import Board

    for flag, given in (
        ("--usb", getattr(args, "usb", False)),
        ("--usb-detach", getattr(args, "usb_detach", [])),
    ):
        if given:
            raise ConfigError(
                "the phone's USB link is the firmware's: it needs the firmware board (--avr, board=firmware)",
                flag,
            )
    cfg = board_config(args)
    board = Board(cfg, clock if clock is not None else WallClock(), boot_ids=boot_ids)  # type: ignore[arg-type]
    schedule_faults(board.faults, args, cfg)
    return board


def schedule_faults(faults, args: argparse.Namespace, cfg) -> None:  # type: ignore[no-untyped-def]
    """The fault options into ``faults`` (a board's ``FaultInjector``; times relative to its clock's
    start): the Python board's, or the firmware board's in a world (:mod:`.avr.stepped`)."""
    with _named_by_option():
        faults.link(corrupt=args.corrupt, drop=args.drop, direction=args.fault_direction)
    for spec in args.stall:
        at, duration = parse_stall(spec)
        faults.stall(duration, at=at)
    for t in args.hang_at:
        faults.hang(at=parse_time(str(t), "--hang-at"))
    for spec in args.sag:
        volts, sag_at, ramp = parse_sag(spec)
        faults.sag(drop_v=volts, ramp_s=ramp, at=sag_at)
    for spec in args.sag_ohms:
        ohms, sag_at, ramp = parse_sag(spec, "--sag-ohms", MAX_SAG_OHMS)
        faults.sag(extra_resistance_ohm=ohms, ramp_s=ramp, at=sag_at)
    full = cfg.power.battery.cells * 4.2
    for t in args.brownout_at:
        faults.sag(drop_v=full, at=parse_time(str(t), "--brownout-at"), duration=0.3)
    for spec in args.phone_gap:
        at, duration = parse_stall(spec, "--phone-gap")
        faults.phone_gap(duration, at=at)
    for spec in args.unplug:
        at, duration = parse_stall(spec, "--unplug")
        faults.unplug(duration, at=at)
    for spec in args.noise:
        at, duration, p = parse_noise(spec)
        faults.noisy_link(p, duration, at=at)
    for spec in args.phone_jump:
        at, offset = parse_jump(spec)
        faults.phone_jump(offset, at=at)
    for spec in args.phone_spoof:
        at, kind = parse_spoof(spec)
        with _named_by_option():  # the kind is the world's to check: said by the option typed
            faults.phone_spoof(kind, at=at)
    for spec in args.dead_esc:
        ch, esc_at = parse_dead_esc(spec)
        if ch >= cfg.n_channels:  # the API checks too; here the error names the option
            raise ConfigError(f"channel {ch} does not exist (the board has {cfg.n_channels})", "--dead-esc")
        faults.dead_esc(ch, at=esc_at)


def _board(args: argparse.Namespace) -> Any:
    """The Python board, or with ``--avr`` the firmware stepped under simavr (a FirmwareBoard, with the
    interface the servers and the world call), on the wall clock."""
    if args.avr is None:  # a board process: boot ids no other process (this one restarted) announces
        return make_board(args, boot_ids=random.Random(os.urandom(16)))
    from hil.timing.clock import WallClock

    from .avr.stepped import firmware_board

    return firmware_board(args, WallClock())


def board_and_world(args: argparse.Namespace, scenario: object | None):  # type: ignore[no-untyped-def]
    """The board the options describe and, with a scenario, the world it drives — ready before the
    board's clock starts: the world's kernels loaded (a twin flown in lockstep) before the board and its
    clock are made, its first batch stepped right after. (Loading them on the world's first real-time
    pass left it ~400 ms behind the board's clock at start-up, reported as a machine too slow.)"""
    if scenario is None:
        return _board(args), None
    from .world import World, load_kernels

    load_kernels(scenario, board_config(args))
    board = _board(args)
    world = World(scenario, board)
    world.prepare()
    return board, world


def _given(argv: Sequence[str] | None) -> dict[str, Any]:
    """The options the command line itself gives (``argv``; None: ``sys.argv``), without argparse's
    defaults: parsed again by firmware-sim's parser with every default suppressed, so that an option left
    out is told from one given at its default value."""
    parser = build_parser()
    for action in parser._actions:
        action.default = argparse.SUPPRESS
    return vars(parser.parse_args(argv))


def world_options(args: argparse.Namespace, argv: Sequence[str] | None, scenario: Scenario) -> list[str]:
    """The world's ``[board]`` and ``[faults]`` as this board's options (``args``, parsed from ``argv``),
    in place: the same scenario that the host runs against this board must set the board it serves (its
    ``link_timeout`` of 1 s was served as the 0.25 s default, its ``hang_at`` never happened).

    A setting the command line (or a ``spawn://…?world=`` URL) leaves out is the scenario's. One it gives
    overrides the scenario's single-valued setting (a benchmark's faster ``frame_rate`` for the same
    world) and is said: the returned lines, one per setting overridden, name both. The repeatable faults
    add up: the scenario's, then the command line's that the scenario does not already have (a URL that
    repeats the scenario's own options beside ``world=`` schedules each fault once)."""
    parser = build_parser()
    repeatable = {a.dest for a in parser._actions if isinstance(a, argparse._AppendAction)}
    own = parser.parse_args(scenario.firmware_sim_argv())  # the scenario's values, through the same parser
    given = _given(argv)
    where = scenario.path if scenario.path is not None else scenario.name
    notes: list[str] = []
    for table, options in (("board", scenario.board_options), ("faults", scenario.fault_options)):
        for key in options:
            value = getattr(own, key)
            if key in repeatable:
                setattr(args, key, [*value, *(v for v in getattr(args, key) if v not in value)])
            elif key in given and given[key] != value:
                option = "--" + key.replace("_", "-")
                notes.append(f"{option} {given[key]} overrides the world's {table}.{key} = {value} ({where})")
            else:
                setattr(args, key, value)
    return notes


def _say_harness_died(died: HarnessDied, where: str) -> None:
    """One line naming the board that went (a ``HarnessDied``), after what the harness itself said when it
    exited by itself with an error (a crashed firmware's message); a killed one said nothing new."""
    from .avr.harness import HarnessDied

    if died.returncode > 0 and died.said:
        print(died.said, file=sys.stderr)
    gone = HarnessDied(died.pid, died.returncode, where)
    print(f"firmware-sim: error: {gone}", file=sys.stderr, flush=True)


def _usb_line(source: Any) -> str:
    """The stop summary's words on the phone of the firmware on USB (the harness's ``usbstate``, from the
    stepped board or the harness server): its mode, the identity the board sent it, the app's bytes;
    empty if the harness cannot answer."""
    try:
        usb = source.usb_state()
    except LinkError:
        return ""
    who = " / ".join(s for s in usb.strings[:2] if s) or "no strings"
    error = f", model error: {usb.error}" if usb.error else ""
    return (
        f"; phone on USB: {usb.mode_name} ({who}), app wrote {usb.to_board} bytes, read {usb.from_board}, "
        f"{usb.dropped} dropped while no accessory was open{error}"
    )


def _check_phone_sender(url: str) -> None:
    """Refuse at start a ``--phone`` address the world's phone could never reach (a :class:`ConfigError`
    naming ``--phone``): port 0 (a listener's "any free port"), and for UDP an IPv6 address or a name without
    an IPv4 one (its sender's socket is IPv4). Accepted, every datagram or request failed, only counted."""
    from urllib.parse import urlsplit

    from hil.link.sources.phone_udp import sender_address
    from hil.link.sources.stream import split_url

    if urlsplit(url).scheme == "udp":
        sender_address(url, "--phone")
    else:
        split_url(url, "http", "http://HOST:PORT/PATH", default_port=80, where="--phone", sending=True)


def _close_at_start(server: Any, board: Any) -> None:
    """What start-up made before an error ended it: the server (its pty, its bus) and a stepped firmware
    board's harness. Errors closing them are logged: the one that ended start-up is the one to say."""
    for part in (server, board):
        if part is None:
            continue
        try:
            part.close()
        except Exception:  # noqa: BLE001 — the start-up error is what the user must see
            logging.getLogger(__name__).warning("closing %r after a failed start", part, exc_info=True)


class StopOnSignals:
    """``firmware-sim``'s handler of :data:`~hil.runtime.held_signals.STOP_SIGNALS` (SIGINT, SIGTERM, and
    SIGHUP: the terminal it was started from closed), installed for the whole of :func:`main`.

    A signal is noted and, once there is a server, stops it: the serving loop returns, the pty is closed,
    the symlink removed and the summary said, status 0. Installed before anything is made, because every
    moment of a start-up (its imports, a world's kernels loading, the pty and its symlink made) is one a
    signal may land on: SIGINT there met Python's handler (a ``KeyboardInterrupt`` traceback), SIGTERM and
    SIGHUP the OS's default (the process gone, its ``--link`` symlink left pointing at nothing), and
    SIGHUP at any moment did the same, serving or not. A signal during start-up lets the start-up finish
    (nothing is left half made) and then serves nothing."""

    def __init__(self) -> None:
        self.received: list[signal.Signals] = []
        self._server: Any = None
        self._previous: dict[int, Any] = {}

    def install(self) -> StopOnSignals:
        """Put this handler in place of the stop signals' current ones. Only the main thread can (Python
        runs handlers there); :func:`main` called from another thread installs nothing."""
        from hil.runtime.held_signals import STOP_SIGNALS

        if threading.current_thread() is not threading.main_thread():
            return self
        for signum in STOP_SIGNALS:
            self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def restore(self) -> None:
        """The handlers that were there before :meth:`install`."""
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def serving(self, server: Any) -> None:
        """From now on a signal stops ``server`` (a ``BoardServer``); one received already stops it now."""
        self._server = server
        if self.received:
            server.stop()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.received.append(signal.Signals(signum))
        server = self._server
        if server is not None:
            server.stop()


def main(argv: Sequence[str] | None = None) -> int:
    """``firmware-sim argv``; its exit status. SIGINT, SIGTERM and SIGHUP end it cleanly from the first
    line on (:class:`StopOnSignals`); the handlers that were there come back when it returns."""
    stop = StopOnSignals().install()
    try:
        return _main(argv, stop)
    finally:
        stop.restore()


def _can_interface(url: str) -> str:
    """The python-can interface ``--can``'s value names (``virtual`` of ``virtual/x?node=1`` or of
    ``can://virtual/x``), lower-cased."""
    rest = url.split("://", 1)[1] if "://" in url else url
    return rest.split("/", 1)[0].split("?", 1)[0].strip().lower()


def _main(argv: Sequence[str] | None, stop: StopOnSignals) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.can is not None and (args.link or args.no_hold):
        parser.error("--can serves a CAN bus: it cannot be combined with --link or --no-hold")
    if args.eeprom is not None and args.avr is None:
        parser.error("--eeprom is the firmware's EEPROM image: it needs --avr (the emulator keeps none)")
    if args.usb and args.avr is None:
        parser.error(
            "--usb is the firmware's USB link (the phone's accessory app on its pty): it needs --avr"
        )
    if args.usb and args.can is not None:
        parser.error(
            "--usb puts the host on the phone's accessory link, --can on a CAN bus bridged to UART0: "
            "the firmware listens to one link, choose one"
        )
    if args.can is not None and _can_interface(args.can) == "virtual":
        parser.error(
            f"--can {args.can}: python-can's virtual bus lives inside one process, and no host in another "
            "process can reach it (firmware-sim would wait for one forever): serve on a bus processes share, "
            "e.g. --can udp_multicast/239.74.163.2?port=43113 or --can socketcan/vcan0"
        )
    phone_faults = {
        "--phone-jump": args.phone_jump,
        "--phone-spoof": args.phone_spoof,
        "--phone-gap": args.phone_gap,
    }
    given = [flag for flag, values in phone_faults.items() if values]
    if given and args.world is None:  # accepted and ignored, they were: there is no phone without a world
        parser.error(f"{given[0]} acts on the world's phone: it needs --world")
    if args.usb_detach and (not args.usb or args.world is None):
        parser.error(
            "--usb-detach pulls the phone off the stepped firmware board: it needs --avr --usb --world"
        )
    level = logging.WARNING - 10 * min(args.verbose + 1, 2)
    logging.basicConfig(
        level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )
    from .avr.harness import HarnessDied
    from .servers.base import BoardServer
    from .servers.can_server import CanServer
    from .servers.pty_server import PtyServer
    from .servers.status import StatusLines

    board: Any = None  # None: the harness serves the firmware on its pty itself (.avr.serve)
    world = None
    server: BoardServer | None = None
    streamer = None
    try:
        scenario = None
        if args.world is not None:
            from hil.link.sources import phone_url
            from hil.scenario import load_scenario

            scenario = load_scenario(args.world)
            if args.units is not None and args.units != scenario.n_units:  # it was silently overridden
                raise ConfigError(
                    f"--units {args.units}, but the world {args.world} has {scenario.n_units} units (--world "
                    "sets them: leave --units out)",
                    "firmware-sim --units",
                )
            args.units = scenario.n_units
            for note in world_options(args, argv, scenario):
                print(f"firmware-sim: {note}", file=sys.stderr)
            try:
                args.phone = phone_url(args.phone)
            except ConfigError:
                raise
            except ValueError as exc:  # urllib's own refusal ("Invalid IPv6 URL": an unbalanced bracket)
                raise ConfigError(f"{args.phone!r}: not a URL ({exc})", "--phone") from None
            _check_phone_sender(args.phone)
        elif args.units is None:
            args.units = DEFAULT_UNITS
        if args.avr is not None and args.world is None and args.can is None:
            from .avr.serve import server_from_args

            server = server_from_args(args, board_config(args))
        else:  # the Python board, or the firmware stepped from here (.avr.stepped), behind our server
            board, world = board_and_world(args, scenario)
            if args.can is not None:
                server = CanServer(board, args.can)
            else:
                server = PtyServer(board, link=args.link, hold_slave=not args.no_hold)
        if world is not None:  # its phone's sender refusing its address is an error here, the server closed
            from .world import WorldStreamer

            streamer = WorldStreamer(world, server.lock, args.phone).start()
    except HilError as exc:  # a harness refusing its options at start-up says why here too: status 2
        _close_at_start(server, board if args.avr is not None else None)
        print(f"firmware-sim: error: {exc}", file=sys.stderr)
        return 2
    assert server is not None  # made above, or the error returned
    stop.serving(server)
    print(server.path, flush=True)
    where = f" (link {args.link})" if args.link else ""
    print(
        f"firmware-sim: {args.units} units on {server.path}{where}; waiting for a host; ^C to stop",
        file=sys.stderr,
        flush=True,
    )
    status = StatusLines(server).start()
    harness_died = False
    usb_line = ""
    try:
        server.serve(duration=args.duration)
    except HarnessDied as exc:  # the firmware's simulator went: one line naming the board, exit 3
        harness_died = not server.stopping()
        if harness_died:
            _say_harness_died(exc, server.path)
    finally:
        try:
            status.stop()
        finally:  # whatever the status thread met, the pty is closed and the symlink removed
            if args.usb and not harness_died:  # the harness's phone, before the harness stops
                usb_line = _usb_line(board if board is not None else server)
            server.close()
            if streamer is not None:
                try:
                    streamer.close()
                except LinkError as exc:  # the world thread met the harness's death first: the same end
                    died = exc.__cause__
                    if not isinstance(died, HarnessDied):
                        raise
                    if not harness_died:
                        _say_harness_died(died, server.path)
                    harness_died = True
            if args.avr is not None and board is not None:
                board.close()  # the stepped firmware's harness: stopped, its EEPROM saved back
    stats = server.stats
    link_line = (
        f"{stats.frames_in} frames in, {stats.frames_out} out; host left {stats.host_gone} time(s), "
        f"came back {stats.reconnects}; {stats.errors} link error(s)"
    )
    world_line = ""
    if streamer is not None:
        lag = streamer.lag.stats
        world_line = (
            f"; world: {streamer.world.steps} plant steps, {streamer.sender.sent} phone messages "
            f"({streamer.sender.failed} failed), started {lag.startup_lag_s * 1e3:.0f} ms behind the board's "
            f"clock, then {lag.episodes} lag episode(s), at most {lag.max_lag_s * 1e3:.0f} ms behind"
        )
    resets = ""
    if board is not None:  # the first is the power-on (a firmware board that never ran: none at all)
        resets = f"; {max(len(board.resets) - 1, 0)} reset(s)"
    _tell(
        f"firmware-sim: stopped; {stats.bytes_in} bytes in, {stats.bytes_out} out, {link_line}"
        f"{resets}{world_line}{usb_line}"
    )
    if stats.dropped_out:
        _tell(
            f"firmware-sim: {stats.dropped_out} bytes of the board's output were dropped: written while no "
            "host had the port open (before it connected, after it left) or faster than it read (the "
            "board keeps at most 4 KiB, like a UART buffer)"
        )
    return EXIT_HARNESS_DIED if harness_died else 0


def _tell(line: str) -> None:
    """``line`` on stderr, unless stderr is gone — the terminal closed under the command (EIO; it is
    then ending on that terminal's SIGHUP) or a pipe nobody reads: the summary is said where it can be,
    and its failing to be said is no error of the board's (it once ended a clean stop in a traceback,
    exit status 1)."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):  # ValueError: the stream itself closed
        pass


if __name__ == "__main__":
    sys.exit(main())
