"""``hil calibrate esc | sweep | unit``: calibrating a bench through its board (a port URL).

The same commands work against a real board on a serial port, ``spawn://firmware-sim`` (the emulator on
a pty), ``firmware-sim --avr`` (the C firmware under simavr) and ``emu://`` (the emulator in this
process, in simulated time unless ``--realtime``). Registered by :mod:`hil.cli.calibrate`.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from hil.cli._parser import given_path

_MAPS = ("rotor", "gimbal_rate", "gimbal_angle")
CONNECT_WITHIN_S = 5.0
"""How long the first handshake is tried again while the port is away (s): a board plugged back, a
firmware-sim restarted — a bench tool waits seconds, not ``hil run``'s outage bound."""

_ESC_EXAMPLES = """examples:
  # teach unit 2's ESC 1000..2000 us: the board cuts the ESC supply (or asks for it), times every step
  hil calibrate esc --port /dev/ttyACM0 --unit 2 --confirm-unloaded
  # an ESC whose acknowledgement beeps take longer
  hil calibrate esc --port /dev/ttyACM0 --unit 0 --confirm-unloaded --high-ms 5000
"""

_SWEEP_EXAMPLES = """examples:
  # rotor of unit 0, 1000..2000 us in 40 us steps up and down: bench/unit0_rotor.csv
  hil calibrate sweep --port /dev/ttyACM0 --unit 0 --out-dir bench
  # the gimbal rate of units 0-3 together, stop above 6 A or under 10.5 V
  hil calibrate sweep --port /dev/ttyACM0 --unit 0 --unit 1 --unit 2 --unit 3 --map gimbal_rate \\
      --out-dir bench --max-current 6 --min-battery 10.5
  # against the emulator (a bench of dispersed units), in simulated time
  hil calibrate sweep --port "emu://?unit_spread=7&esc_supply_switch=1" --unit 1 --out-dir /tmp/bench
"""

_UNIT_EXAMPLES = """examples:
  # everything for units 0-3: teach the ESCs, sweep the three maps, fit, upload, read back, verify, save
  hil calibrate unit --port /dev/ttyACM0 --unit 0 --unit 1 --unit 2 --unit 3 --program-esc \\
      --confirm-unloaded -o cal/array.toml --bench-dir bench
  # refit only the rotor of unit 2 (its gimbal maps are kept from cal/array.toml)
  hil calibrate unit --port /dev/ttyACM0 --unit 2 --maps rotor -o cal/array.toml --bench-dir bench
  # a whole emulated bench in simulated time
  hil calibrate unit --port "emu://?unit_spread=7&esc_supply_switch=1" --unit 0 --unit 1 --program-esc \\
      --confirm-unloaded -o /tmp/cal.toml --bench-dir /tmp/bench
"""


def register_actions(actions: Any) -> None:
    """Add ``esc``, ``sweep`` and ``unit`` to ``hil calibrate``'s actions."""
    e = actions.add_parser(
        "esc",
        help="teach a rotor ESC its endpoints through the board (the board times the procedure)",
        description="Run the ESC endpoint procedure on a unit's rotor channel: the board powers the ESC up "
        "at the high endpoint (cutting its supply, or asking for it), waits for the acknowledgement, then "
        "gives the low endpoint and goes back to the safe pulse. The board must be disarmed. A board "
        "without a supply switch waits up to 60 s for you to connect the ESC's supply and press Enter; the "
        "link is kept alive meanwhile.",
        epilog=_ESC_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _board_options(e)
    _esc_options(e)
    e.set_defaults(func=run_esc)

    s = actions.add_parser(
        "sweep",
        help="step a rotor or gimbal channel over its range and write the bench CSV fit reads",
        description="Sweep the pulse width of the chosen map's channel of each unit (up and down, settle "
        "and dwell, rate-limited, with a battery current/voltage guard) and record the response the "
        "board's telemetry reports: <out-dir>/unit<N>_<map>.csv with the board, unit, date and battery, "
        "rewritten after every step and marked '# status: partial' until the sweep completes (an interrupted "
        "sweep keeps what it measured). Each step is printed with the time left.",
        epilog=_SWEEP_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _board_options(s)
    s.add_argument("--map", choices=_MAPS, default="rotor", help="which channel and response (rotor)")
    s.add_argument("--out-dir", type=given_path, required=True, help="directory for the bench CSV")
    s.add_argument("--range", default="1000:2000", metavar="LOW:HIGH", help="pulse range, us (1000:2000)")
    s.add_argument("--step", type=int, metavar="US", help="step, us (rotor 40, gimbal rate 20, angle 25)")
    s.add_argument("--tolerance", type=float, help="settled when the response varies less (rad/s or rad)")
    _sweep_options(s)
    s.set_defaults(func=run_sweep_cmd)

    u = actions.add_parser(
        "unit",
        help="sweep, fit, upload, read back and verify units; save them in the array's calibration file",
        description="Calibrate units in one go: optionally teach their ESCs, sweep each map, fit (refusing "
        "a fit that fails validation), upload through the CALIBRATION transfer, read back, verify with "
        "setpoints through the uploaded maps (tracking error per point; on failure the previous sets are "
        "put back), and save the units in the calibration file, each unit's fit plot beside it "
        "(<out stem>-unit<N>.png). Every step is printed with the time left; an interrupt leaves the board "
        "at rest, says its state, and keeps the sweep's partial bench CSV, marked '# status: partial'.",
        epilog=_UNIT_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _board_options(u)
    u.add_argument("-o", "--out", type=given_path, required=True, help="the array's calibration file (TOML)")
    u.add_argument("--bench-dir", type=given_path, required=True, help="where the sweeps' bench CSVs go")
    u.add_argument("--maps", default=",".join(_MAPS), help="maps to calibrate, comma-separated (all three)")
    u.add_argument("--program-esc", action="store_true", help="teach the ESCs their endpoints first")
    _esc_options(u)
    u.add_argument("--rotor-step", type=int, default=40, metavar="US", help="rotor sweep step (40)")
    u.add_argument("--rate-step", type=int, default=20, metavar="US", help="gimbal rate sweep step (20)")
    u.add_argument("--angle-step", type=int, default=25, metavar="US", help="gimbal angle sweep step (25)")
    u.add_argument("--rotor-knots", type=int, default=9, help="knots of the throttle curve, 3..16 (9)")
    u.add_argument("--gimbal-rate-knots", type=int, default=6, help="knots each side of the dead zone (6)")
    u.add_argument("--gimbal-angle-knots", type=int, default=9, help="knots of the angle table (9)")
    u.add_argument("--no-verify", action="store_true", help="skip the verification sweep")
    u.add_argument("--rotor-tolerance", type=float, default=0.02, help="verification: of full speed (0.02)")
    u.add_argument("--rate-tolerance", type=float, default=0.05, help="verification: rad/s (0.05)")
    u.add_argument("--angle-tolerance", type=float, default=0.03, help="verification: rad (0.03)")
    _sweep_options(u)
    u.set_defaults(func=run_unit)


def _board_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("board")
    g.add_argument("--port", required=True, metavar="URL", help="the board: a serial port or transport URL")
    g.add_argument(
        "--unit", type=int, action="append", required=True, metavar="N", help="unit number (repeatable)"
    )
    g.add_argument(
        "--realtime", action="store_true", help="with --port emu://...: wall-clock time (default: simulated)"
    )
    g.add_argument(
        "--connect-within",
        type=float,
        default=CONNECT_WITHIN_S,
        metavar="S",
        help="a port that vanishes or cannot be opened at the first handshake (a board unplugged and plugged "
        f"back, a firmware-sim restarting) is tried again for this long ({CONNECT_WITHIN_S:g}); a board that "
        "answers nothing, another protocol or a port another host holds fails at once",
    )


def _esc_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("ESC endpoint programming")
    g.add_argument(
        "--confirm-unloaded",
        action="store_true",
        help="I confirm the rotor is off or unloaded (the ESC sees full throttle); required to program",
    )
    g.add_argument("--esc-low", type=int, default=1000, metavar="US", help="low endpoint to teach (1000)")
    g.add_argument("--esc-high", type=int, default=2000, metavar="US", help="high endpoint to teach (2000)")
    g.add_argument("--supply-off-ms", type=int, default=1500, help="ESC supply off before power-up (1500)")
    g.add_argument("--high-ms", type=int, default=3000, help="high endpoint held after power-up (3000)")
    g.add_argument("--low-ms", type=int, default=2000, help="low endpoint held (2000)")


def _sweep_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("sweep (and verification) steps")
    g.add_argument("--directions", choices=("up", "down", "both"), default="both", help="(both)")
    g.add_argument("--settle", type=float, default=0.3, metavar="S", help="minimum settle time (0.3)")
    g.add_argument("--settle-window", type=float, default=0.5, metavar="S", help="steadiness window (0.5)")
    g.add_argument("--settle-max", type=float, default=10.0, metavar="S", help="give up settling after (10)")
    g.add_argument("--dwell", type=float, default=0.25, metavar="S", help="averaging time per step (0.25)")
    g.add_argument("--rate-limit", type=float, default=2000.0, metavar="US/S", help="pulse slew (2000)")
    g.add_argument("--max-current", type=float, default=8.0, metavar="A", help="battery current guard (8)")
    g.add_argument("--min-battery", type=float, metavar="V", help="battery voltage floor (none)")


# --------------------------------------------------------------------------- shared
def _client(args: argparse.Namespace) -> Any:
    """The client of the board at ``args.port``, connected (:func:`hil.link.board.connect_within`): a port
    away at the first handshake is tried again for ``--connect-within`` s, each retry said on stderr."""
    from hil.cli.run import MAX_OPTION_S
    from hil.link.board import BoardClient, ConnectRetry, connect_within
    from hil.timing.clock import LockstepClock
    from protocol.errors import ConfigError, HandshakeError, LinkError

    bound = args.connect_within
    if not (math.isfinite(bound) and 0 <= bound <= MAX_OPTION_S):  # 1e308: a wait for ever
        raise ConfigError(f"{bound!r} must be a number of seconds in 0..{MAX_OPTION_S:g}", "--connect-within")

    def said(retry: ConnectRetry) -> None:
        print(
            f"hil calibrate: no session with the board at {args.port} yet ({retry.error}); trying again in "
            f"{retry.delay_s:.2f} s (tried for {retry.waited_s:.1f} s of {bound:g} s)",
            file=sys.stderr,
            flush=True,
        )

    lockstep = args.port.startswith("emu:") and not args.realtime
    client = BoardClient(args.port, clock=LockstepClock() if lockstep else None)
    try:
        connect_within(client, bound, said)
    except LinkError as exc:  # no board, not ours, not free, or not back within the bound: said as such
        client.close()
        kind = HandshakeError if isinstance(exc, HandshakeError) else LinkError
        raise kind(f"no session with the board at {args.port} ({exc}); nothing was done") from exc
    except BaseException as exc:
        client.close()
        if isinstance(exc, KeyboardInterrupt):  # Ctrl-C or SIGTERM before a session: nothing to put to rest
            print(
                f"hil calibrate: no session with the board at {args.port}; nothing was done",
                file=sys.stderr,
            )
        raise
    return client


@contextmanager
def _bench(args: argparse.Namespace) -> Iterator[Any]:
    """The bench link on the board at ``args.port``, closed afterwards. Interrupted (Ctrl-C, or SIGTERM
    from ``timeout``, systemd or a CI cancel: :mod:`hil.cli._signals`), the board is put back to rest
    first — its outputs to the base pulses, Disarm (which also aborts an ESC being taught, to its minimum
    pulse), SETPOINT mode (``BenchLink.safe``) — and the state it was left in, as its telemetry reports
    it, is printed; a sweep has kept its partial bench CSV, marked so. Best effort: closing the port alone
    would leave the board to its link watchdog. The signal after the interrupt is held
    (:class:`~hil.runtime.held_signals.HeldSignals`): a second one microseconds after the first landed on
    the entry of the rest and skipped it, said as interrupted by the second; one more gives the rest up,
    said. A command that fails after it moved the outputs (a board lost, reset or stalled under it; a
    refused fit) does the same before its error is printed; a board that cannot be reached is said to
    be so."""
    from hil.calibration.benchlink import BenchLink
    from hil.runtime.held_signals import HeldSignals
    from protocol.errors import HilError

    client = _client(args)
    link = BenchLink(client)
    with HeldSignals():
        try:
            yield link
        except KeyboardInterrupt:
            print(f"hil calibrate: {_left_at_rest(link)}", file=sys.stderr, flush=True)
            raise
        except HilError:
            # failed after the outputs were moved (a board lost, reset or stalled; a refused fit): rest, said
            if link.touched:
                print(f"hil calibrate: {_left_at_rest(link)}", file=sys.stderr, flush=True)
            raise
        finally:
            client.close()


def _left_at_rest(link: Any) -> str:
    """Put the board back to rest and say what state its telemetry then shows."""
    from protocol.errors import HilError
    from protocol.messages import BoardState, ControlMode

    def at_rest(t: Any) -> bool:
        return t.state is not BoardState.ARMED and t.mode is not ControlMode.ESC_CALIBRATION

    try:
        client = link.client
        if not client.connected:  # a board restarted on its port is found again within the back-off
            client.wait_for(lambda: client.connected, 2.0)
        if not client.connected:
            return (
                "the board cannot be reached (its link is down): closing the port leaves it to its link "
                "watchdog, which stops its rotors within its timeout"
            )
        link.safe()
        first = link.latest(at_rest, timeout=2.0)
        # A pulse's width changes at its frame's start, never within a pulse: telemetry sent within a
        # frame of the state change may still show the width before it (an ESC being taught at 2000 us).
        # The outputs are read from telemetry two frame periods later.
        info = link.client.info
        frame_ms = 2000.0 / (info.frame_rate_hz if info is not None and info.frame_rate_hz else 50)
        tel = link.latest(
            lambda t: at_rest(t) and (t.time_ms - first.time_ms) % 2**32 >= frame_ms, timeout=2.0
        )
    except (HilError, KeyboardInterrupt) as exc:
        return (
            f"could not put the board back to rest ({exc!r}); closing the port leaves it to its link "
            "watchdog, which stops its rotors within its timeout"
        )
    widths = tel.pulses_us
    outputs = "; ".join(
        f"unit {u} gimbal {widths[2 * u]} us, rotor {widths[2 * u + 1]} us" for u in range(len(widths) // 2)
    )
    return (
        f"the board was left {tel.state.name} in {tel.mode.name} mode (no ESC being taught), its outputs at "
        f"rest: {outputs}"
    )


_SETTLING_OPTIONS = {
    "Settling.settle_s": "--settle",
    "Settling.window_s": "--settle-window",
    "Settling.max_s": "--settle-max",
    "Settling.dwell_s": "--dwell",
}
"""The option that sets each of :class:`~hil.calibration.benchlink.Settling`'s fields."""


def _settling(args: argparse.Namespace) -> Any:
    """The settling the options describe; a refused value is a :class:`ConfigError` naming its option."""
    from hil.calibration.benchlink import Settling
    from protocol.errors import ConfigError

    try:
        return Settling(args.settle, args.settle_window, args.settle_max, args.dwell)
    except ConfigError as exc:
        raise ConfigError(exc.detail, _SETTLING_OPTIONS.get(exc.where, exc.where)) from None


def _guard(args: argparse.Namespace) -> Any:
    from hil.calibration.benchlink import Guard

    return Guard(args.max_current, args.min_battery)


def _program(args: argparse.Namespace) -> Any:
    from hil.calibration.esc import EscProgram

    return EscProgram(args.esc_low, args.esc_high, args.supply_off_ms, args.high_ms, args.low_ms)


def say(line: str) -> None:
    """A line on stdout, flushed at once (the operator watches it; stdout may be a pipe). A stdout that
    refuses it — a pipe whose reader is gone (``hil calibrate unit | sed '/read back/q'``, ``show | head
    -1``), a terminal that hung up — ends the output, not the command, as ``hil run``'s progress lines do
    (:func:`hil.cli.run.say`): a BrokenPipeError raised mid-upload left a set on the board unverified and
    ended in a traceback. stdout then goes to the null device, so the exit's flush of what was left in
    its buffer fails no more (Python's note on SIGPIPE)."""
    try:
        print(line, flush=True)
    except (OSError, ValueError):
        _stdout_gone()


def _stdout_gone() -> None:
    import os

    with contextlib.suppress(OSError, ValueError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


_print = say


# --------------------------------------------------------------------------- esc
def run_esc(args: argparse.Namespace) -> int:
    from hil.calibration.esc import program_esc

    from ._operator import TerminalOperator

    program = _program(args)
    operator = TerminalOperator()
    with _bench(args) as link:
        for unit in args.unit:
            outcome = program_esc(
                link,
                unit,
                program,
                confirm_unloaded=args.confirm_unloaded,
                operator=operator,
                report=_print,
            )
            phases = " -> ".join(p.name for p in outcome.phases)
            say(f"unit {unit}: ESC taught {outcome.low_us}-{outcome.high_us} us ({phases})")
    return 0


# --------------------------------------------------------------------------- sweep
def _range(text: str) -> tuple[int, int]:
    from protocol.errors import ConfigError

    low, sep, high = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return int(low), int(high)
    except ValueError:
        raise ConfigError(f"{text!r} is not LOW:HIGH in us (e.g. 1000:2000)", "--range") from None


def run_sweep_cmd(args: argparse.Namespace) -> int:
    from hil.calibration.bench import BenchKind
    from hil.calibration.sweep import SweepPlan, not_written, run_sweep

    low, high = _range(args.range)
    plan = SweepPlan(
        BenchKind(args.map),
        start_us=low,
        stop_us=high,
        step_us=args.step,
        directions=args.directions,
        settling=_settling(args),
        rate_limit_us_s=args.rate_limit,
        tolerance=args.tolerance,
        guard=_guard(args),
    )
    paths = {unit: args.out_dir / f"unit{unit}_{args.map}.csv" for unit in args.unit}
    _check_before_connecting(args.unit, paths)
    with _bench(args) as link:
        results = run_sweep(link, args.unit, plan, paths=paths, report=_print)
    status = 0
    for unit, result in results.items():
        path = paths[unit]
        unsettled = sum(not r.settled for r in result.rows)
        note = f", {unsettled} unsettled" if unsettled else ""
        if result.rows:
            say(f"unit {unit}: {len(result.rows)} steps{note} -> {path}")
        else:  # stopped before its first step: an earlier sweep's CSV there is kept, not emptied
            say(f"unit {unit}: no step measured: {not_written(path)}")
        if result.stopped:
            print(f"hil calibrate sweep: stopped early: {result.stopped}", file=sys.stderr)
            status = 1
    return status


def _check_before_connecting(units: list[int], paths: dict[int, Path]) -> None:
    """A unit given twice, or a bench CSV that cannot be written (a folder, a FIFO, a folder that is a
    file): refused before the board is opened (``run_sweep`` checks it too, before arming)."""
    from hil.calibration.textfiles import check_writable
    from protocol.errors import ConfigError

    if len(set(units)) != len(units):
        raise ConfigError(f"{list(units)}: give each unit once", "--unit")
    for path in paths.values():
        check_writable(path, f"--out-dir {path.parent}")


# --------------------------------------------------------------------------- unit
def run_unit(args: argparse.Namespace) -> int:
    from hil.calibration.bench import BenchKind
    from hil.calibration.cycle import CycleOptions, calibrate_units, check_cycle
    from hil.calibration.fit import FitOptions
    from hil.calibration.sweep import SweepPlan
    from hil.calibration.verify import VerifyPlan
    from protocol.errors import ConfigError

    from ._operator import TerminalOperator

    names = [m.strip() for m in args.maps.split(",") if m.strip()]
    unknown = [m for m in names if m not in _MAPS]
    if unknown or not names:
        raise ConfigError(f"{args.maps!r}: choose from {', '.join(_MAPS)}", "--maps")
    steps = {"rotor": args.rotor_step, "gimbal_rate": args.rate_step, "gimbal_angle": args.angle_step}
    settling, guard = _settling(args), _guard(args)
    plans = tuple(
        SweepPlan(
            BenchKind(m),
            step_us=steps[m],
            directions=args.directions,
            settling=settling,
            rate_limit_us_s=args.rate_limit,
            guard=guard,
        )
        for m in names
    )
    verify = None
    if not args.no_verify:
        verify = VerifyPlan(
            settling=settling,
            rotor_tolerance=args.rotor_tolerance,
            gimbal_rate_tolerance_rad_s=args.rate_tolerance,
            gimbal_angle_tolerance_rad=args.angle_tolerance,
            guard=guard,
        )
    options = CycleOptions(
        out=args.out,
        bench_dir=args.bench_dir,
        plans=plans,
        fit=FitOptions(
            esc_low_us=args.esc_low,
            esc_high_us=args.esc_high,
            rotor_knots=args.rotor_knots,
            gimbal_rate_knots_per_side=args.gimbal_rate_knots,
            gimbal_angle_knots=args.gimbal_angle_knots,
        ),
        esc=_program(args) if args.program_esc else None,
        verify=verify,
    )
    check_cycle(args.unit, options)  # before the board is opened (calibrate_units checks it again)
    with _bench(args) as link:
        calibrate_units(
            link,
            args.unit,
            options,
            confirm_unloaded=args.confirm_unloaded,
            operator=TerminalOperator(),
            report=_print,
        )
    return 0
