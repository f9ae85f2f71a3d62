"""``hil run``: one closed-loop run of a scenario against the built-in emulator, firmware-sim or a board."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from hil.cli._parser import given_path
from hil.numbers import finite_number

if TYPE_CHECKING:
    from hil.scenario import Scenario

ORDER = 10

EPILOG = """\
examples:
  hil run                                          # built-in emulator, default scenario, lockstep
  hil run --scenario paper-testbed --duration 30   # the paper's air-bearing testbed, 30 s after the slew
  hil run --realtime                               # built-in emulator on the wall clock, phone over UDP
  hil run --board firmware                         # the firmware ELF under simavr drives the world, lockstep
  hil run --scenario my.toml --out runs/             # your own scenario file (see fixtures/scenarios/)
  hil run --gcs                                    # ... watched and commanded from a browser (docs/gcs.md)
  hil run --gcs --pace 5 --duration 60             # lockstep at 5x the wall clock, 60 s after the slew
  hil run --estimator vqf                          # VQF as the host's estimator (pip install vqf)

  # two terminals: the emulated board with its world on a pty, then the host against it
  firmware-sim --world cubesat-1u --link /tmp/vscmg
  hil run --port /tmp/vscmg                         # listens for the world's phone on udp://127.0.0.1:8123

  hil run --port "spawn://firmware-sim?world=cubesat-1u&phone=udp://127.0.0.1:8123"
  hil run --port /dev/ttyACM0 --phone udp://0.0.0.0:8123         # a real board; SensaGram streams here
  hil run --port /dev/ttyACM0 --phone http://0.0.0.0:8123/       # ... or Sensor Logger's HTTP Push

writes RUN_DIR/telemetry.csv (one row per control tick), telemetry_codes.json (what its coded columns'
numbers mean), events.jsonl, summary.json, scenario.toml and plots/; `hil report RUN_DIR` redraws the
plots. Scenarios shipped: see fixtures/scenarios/.

exit status:
  0  completed: the run's time after the slew's start is up, the board and the phone in hand at the end
  1  ended early or incomplete: interrupted by SIGINT (Ctrl-C), SIGTERM (timeout, systemd, a CI cancel) or
     SIGHUP (its terminal or ssh session closed) — the board disarmed, summary.json saying
     "interrupted (SIGTERM)" —, aborted from the ground station, left disarmed by the operator at the end,
     the final Disarm not confirmed, the time limit reached before the slew started, the run's time up with
     the board not in hand and armed, the plots failed, or an interrupt after the run ended (while its
     summary printed or its plots were drawn: the plots are stopped, summary.json says how the run itself
     ended)
  2  an error: bad options or scenario, a port that cannot be opened, a board that never answered or is
     incompatible, no phone stream, a reader thread's failure, a run directory the disk refused mid-run
     (full: the board is disarmed, summary.json says which file)
  3  lost: the board (or the phone) was lost and not back within --recover-within (or at the end)
  interrupted before the run starts (while the kernels compile): 130 (SIGINT), 143 (SIGTERM) or 129
  (SIGHUP), no run directory
"""

EXIT_COMPLETED, EXIT_INCOMPLETE, EXIT_ERROR, EXIT_LOST = 0, 1, 2, 3
MAX_FAULT_LINES = 12  # faults listed in the printed summary; all of them are in summary.json


MAX_OPTION_S = 86_400.0
"""The longest ``--duration``, ``--phone-wait`` or ``--recover-within`` of ``hil run`` (a day, a
scenario's longest ``duration_s``): ``--recover-within 1e308`` waited for ever on a port that is never
there."""


def seconds(text: str) -> float:
    """An argparse type: a finite, positive number of seconds (``nan``, ``inf``, 0 and below refused)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of seconds: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number of seconds > 0, got {text!r}")
    return value


def run_seconds(text: str) -> float:
    """:func:`seconds`, at most :data:`MAX_OPTION_S`: a run's bounds and waits."""
    value = seconds(text)
    if value > MAX_OPTION_S:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_OPTION_S:g} s (a day), got {text!r}")
    return value


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "run",
        help="closed-loop run: estimator + controller driving a board (built-in emulator by default)",
        description="Arm the board, spin the rotors up, let the estimator converge, slew to the scenario's "
        "target and hold, logging everything into a run directory.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--port", metavar="URL", help="board transport (default: the built-in emulator)")
    p.add_argument("--scenario", default="cubesat-1u", metavar="NAME|FILE", help="default cubesat-1u")
    p.add_argument(
        "--estimator",
        metavar="NAME",
        help="the host's estimator instead of the scenario's [estimator] kind, with its default settings: "
        "variational (the default), vqf (pip install vqf), or an installed package's",
    )
    p.add_argument(
        "--board",
        choices=("emulator", "firmware"),
        help="the built-in board: the Python emulator (the default) or the firmware ELF under simavr "
        "(make -C firmware; emu://?board=firmware)",
    )
    p.add_argument(
        "--duration",
        type=run_seconds,
        metavar="S",
        help="run this long after the slew starts (default: the scenario's duration_s)",
    )
    timing = p.add_mutually_exclusive_group()
    timing.add_argument("--realtime", action="store_true", help="wall clock (default with --port)")
    timing.add_argument("--lockstep", action="store_true", help="simulated time (default without --port)")
    p.add_argument(
        "--phone",
        metavar="URL",
        help="with --port: listen for the phone here (udp://HOST:PORT: SensaGram, the default "
        "udp://127.0.0.1:8123; http://HOST:PORT/: Sensor Logger; docs/formats.md), or another registered "
        "phone source (vscmg_hil.phone_sources entry points)",
    )
    p.add_argument(
        "--phone-wait",
        type=run_seconds,
        metavar="S",
        help="with --port: wait S s for the phone's first samples (default 10 s)",
    )
    p.add_argument(
        "--recover-within",
        type=run_seconds,
        default=15.0,
        metavar="S",
        help="a board outage (or phone gap) longer than S s ends the run as lost, exit status 3 "
        "(default %(default)g s)",
    )
    p.add_argument(
        "--out", type=given_path, default=Path("runs"), help="where run directories go (default runs/)"
    )
    p.add_argument("--no-plots", action="store_true", help="skip the plots (hil report draws them later)")
    p.add_argument(
        "--gcs",
        nargs="?",
        const="",
        default=None,
        metavar="HOST:PORT",
        help="serve a ground-station page for the run (default 127.0.0.1:8470; its URL, with an access "
        "token, is printed at start; docs/gcs.md)",
    )
    p.add_argument(
        "--pace",
        type=float,
        metavar="X",
        help="lockstep at most X times as fast as the wall clock (1: real time; default with --gcs: 1, "
        "0: as fast as it goes)",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        metavar="N",
        help="a real-time run's threads (and a spawned board) under Linux's SCHED_FIFO at priority N "
        "(1-99): its deadlines kept on a busy machine; needs root, CAP_SYS_NICE or ulimit -r >= N "
        "(docs/runtime-link.md)",
    )
    p.set_defaults(func=run)


class LiveProgress:
    """One status line on stderr, refreshed every half simulated second on a terminal; elsewhere (a log
    file, CI) a line every 5 simulated seconds."""

    def __init__(self, stream=None) -> None:  # type: ignore[no-untyped-def]
        self.stream = sys.stderr if stream is None else stream  # looked up now: tests swap sys.stderr
        self.tty = self.stream.isatty()
        self.every = 0.5 if self.tty else 5.0
        self.next_t = 0.0
        self.gone = False  # the stream refused a write: its terminal closed, its pipe's reader gone

    def __call__(self, host, t: float) -> None:  # type: ignore[no-untyped-def]
        if t < self.next_t or self.gone:
            return
        self.next_t = t + self.every
        trace = host.trace.point_err_deg
        err = f"{trace[-1]:7.3f}°" if trace else "    -   "
        waiting = "" if host.estimate is not None else "  (waiting for the phone)"
        start, end = ("\r", "   ") if self.tty else ("", "\n")
        try:
            self.stream.write(
                f"{start} t {t:6.1f} s  {host.phase.name:<6}  pointing error {err}  "
                f"estimator steps {host.counters.estimator_steps:6d}  failsafes {host.watch.failsafes}"
                f"{'' if host.in_control else '  (board not in hand)'}"
                f"{waiting}{end}"
            )
            self.stream.flush()
        except (OSError, ValueError):  # EIO from a hung-up terminal, EPIPE, a closed stream: the run goes on
            self.gone = True  # (it once ended as an error, the board left armed)


def run(args: argparse.Namespace) -> int:
    """``hil run``: the run, its summary printed, its plots drawn; the exit status (:data:`EPILOG`)."""
    from hil.runtime import RunOptions, check_options
    from hil.runtime import run as run_scenario
    from hil.scenario import load_scenario
    from protocol.errors import ConfigError, HilError

    plotter = None if args.no_plots else Plotter()
    station = None
    try:
        scenario = load_scenario(args.scenario)
        estimator = scenario.estimator.named(args.estimator, "hil run --estimator")
        if args.board is not None and args.port is not None:
            raise ConfigError(
                "chooses the built-in board; with --port the board is the port's "
                '(e.g. "spawn://firmware-sim?board=firmware&world=cubesat-1u")',
                "--board",
            )
        for given, option in ((args.phone, "--phone"), (args.phone_wait, "--phone-wait")):
            if given is not None and args.port is None:  # it was taken for the live phone, then ignored
                raise ConfigError(
                    "with --port only: without one the built-in emulator simulates the phone (a live phone "
                    "beside the built-in emulator: --port emu:// --phone URL)",
                    option,
                )
        scenario = scenario.with_changes(estimator=estimator).with_board(args.board)
        lockstep = True if args.lockstep else (False if args.realtime else None)
        lockstep_run = lockstep if lockstep is not None else args.port is None
        pace = (
            args.pace if args.pace is not None else (1.0 if args.gcs is not None and lockstep_run else None)
        )
        live_phone = {
            "phone": args.phone,
            "phone_wait_s": args.phone_wait,
        }  # RunOptions' defaults if not given
        opts = RunOptions(
            **{name: value for name, value in live_phone.items() if value is not None},
            port=args.port,
            lockstep=lockstep,
            duration_s=args.duration,
            out_root=args.out,
            progress=LiveProgress(),
            pace=pace or None,
            recover_within_s=args.recover_within,
            rt_priority=args.rt_priority,
            report_late_signal=True,
        )
        check_options(scenario, opts)  # a refused option is the one line said, not after the scenario's
        replaced = f" (its estimator replaced: --estimator {args.estimator})" if args.estimator else ""
        say(f"scenario {scenario.name}: {scenario.description}{replaced}", sys.stderr)
        say(f"estimator {estimator.name}: {estimator.describe()}", sys.stderr)
        too_short = too_short_to_judge(scenario, args.duration)
        if too_short is not None:
            say(f"note: {too_short}", sys.stderr)
        for late in faults_after_the_run(scenario, args.duration):
            say(f"note: {late}", sys.stderr)
        if args.port is None:
            from hil.runtime import warmup

            if warmup.needed():
                say("compiling the simulation kernels (once after an install or an edit of them)", sys.stderr)
        if args.gcs is not None:
            station = start_station(args.gcs)
            opts.observer = station.observer
        result = run_scenario(scenario, opts)
    except BaseException as exc:
        try:
            if station is not None:
                station.close()
        finally:
            if plotter is not None:
                plotter.cancel()
        if not isinstance(exc, HilError):
            raise
        say(f"\nhil run: {exc}", sys.stderr)
        return EXIT_ERROR
    if station is not None:
        try:
            station.close()
        except KeyboardInterrupt as exc:  # one while it stops is one after the run: as report_ended's
            return _interrupted_after(result, plotter, "hil run", exc)
        if station.error is not None:  # the page stopped updating; the run did not
            say(f"ground station: its pump failed: {station.error!r}", sys.stderr)
    return report_ended(result, plotter, "hil run")


def too_short_to_judge(scenario: Scenario, duration_s: float | None) -> str | None:
    """What a run of ``duration_s`` (s after the slew starts; None: the scenario's own) cannot judge, said
    before it runs: a run shorter than its slew needs to settle (:meth:`Scenario.time_to_judge`) ends with
    its settle time "NOT met" whatever the system does (a campaign says so in its summary; ``hil run
    --duration 10`` said nothing of it), and the ``--duration`` that would judge it; None when long enough."""
    duration = scenario.slew.duration_s if duration_s is None else duration_s
    shortfall = scenario.time_to_judge().shortfall(duration)
    if shortfall is None:
        return None
    needed = math.ceil(scenario.time_to_judge().total_s)
    return f"{shortfall}: its settle time cannot be met in it (--duration {needed} or more judges it)"


def faults_after_the_run(scenario: Scenario, duration_s: float | None) -> list[str]:
    """The scenario's ``[faults]`` that come after the run's planned end (:meth:`Scenario.planned_length_s`
    with ``duration_s``, else the scenario's), each said: a fault the board is given for board time 80 000 s
    in a run of 44 s never happened, and the run said nothing of it (a fault campaign would call it
    unseen)."""
    from dataclasses import replace

    from hil.scenario.fault_specs import fault_times

    if duration_s is not None:
        scenario = scenario.with_changes(slew=replace(scenario.slew, duration_s=duration_s))
    end = scenario.planned_length_s()
    return [
        f"[faults] {what} comes at {at:g} s, after the run's planned end (~{end:.0f} s: its warm-up, spin-up "
        "and duration): it happens only if the run is that much longer"
        for what, at in fault_times(scenario.fault_options)
        if at > end
    ]


def report_ended(result, plotter: Plotter | None, command: str) -> int:  # type: ignore[no-untyped-def]
    """An ended run's summary printed and its plots drawn (``hil run``'s and ``hil replay --port``'s);
    the exit status. A signal that came while the run wrote its ending
    (:attr:`~hil.runtime.RunResult.late_signal`) stops it here as one that comes now does: the summary
    said, no plots (``hil report RUN_DIR`` draws them), status 1 — never an escaped 130/143/129 with the
    completed run's summary unprinted and the plotter left running."""
    said = False  # the summary printed: an interrupt before it still has it printed
    try:
        late = result.late_signal
        if plotter is not None:
            if late is not None:
                plotter.cancel()
                plotter = None
            else:
                assert result.run_dir is not None
                plotter.draw(result.run_dir)  # drawn in the other process while the summary prints
        say("", sys.stderr)
        _say_summary(result)
        said = True
        if late is not None:
            say(f"{command}: interrupted ({late}) as the run ended: {_no_plots(result)}", sys.stderr)
            return EXIT_INCOMPLETE
        if plotter is not None:
            error = plotter.wait()
            if error:
                say(f"{command}: {error}", sys.stderr)
                return EXIT_INCOMPLETE
        return exit_status(result.summary)
    except KeyboardInterrupt as exc:  # the run has ended and its summary.json is written
        return _interrupted_after(result, plotter, command, exc, said)


def _say_summary(result) -> None:  # type: ignore[no-untyped-def]
    say(format_summary(result.summary), sys.stdout)
    say(f"run directory: {result.run_dir}", sys.stdout)


def _interrupted_after(  # type: ignore[no-untyped-def]
    result, plotter: Plotter | None, command: str, exc: BaseException, said: bool = False
) -> int:
    """An interrupt after the run ended: its plotter's drawing processes stopped (none left running after
    hil), the run's summary printed unless it was (``said``), the interrupt said, status 1."""
    from hil.cli._signals import signal_of

    if plotter is not None:
        plotter.cancel()
    if not said:
        _say_summary(result)
    say(
        f"\n{command}: interrupted ({signal_of(exc).name}) after the run ended: {_no_plots(result)}",
        sys.stderr,
    )
    return EXIT_INCOMPLETE


def _no_plots(result) -> str:  # type: ignore[no-untyped-def]
    """What an interrupt after the run leaves undone, and how to do it."""
    where = result.run_dir if result.run_dir is not None else "RUN_DIR"
    return f"plots not drawn or not all (hil report {where} draws them)"


def say(text: str, stream) -> None:  # type: ignore[no-untyped-def]
    """``text`` and a newline on ``stream``, flushed; nothing when the stream refuses it (its terminal
    hung up, its pipe's reader gone): the run's exit status must not become a traceback's for that."""
    try:
        print(text, file=stream, flush=True)
    except (OSError, ValueError):
        pass


def exit_status(summary: dict) -> int:  # type: ignore[type-arg]
    """The command's exit status for a run's summary (the module's EPILOG)."""
    reason = str(summary.get("exit"))
    if reason == "completed":
        return EXIT_COMPLETED
    if reason.startswith("lost:"):
        return EXIT_LOST
    if reason.startswith("error:"):
        return EXIT_ERROR
    return EXIT_INCOMPLETE


class Plotter:
    """``python -m hil.cli._plotter`` started now, so its imports (matplotlib) overlap the run on another
    core; :meth:`draw` hands it the run directory, :meth:`wait` its error text ("" when the figures are
    drawn)."""

    def __init__(self) -> None:
        import subprocess

        self.process = subprocess.Popen(
            [sys.executable, "-m", "hil.cli._plotter"],
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )  # its own session: a Ctrl-C ends the run (whose plots are still drawn), not it

    def draw(self, run_dir: Path) -> None:
        """Hand the process ``run_dir`` as the file system names it (:func:`os.fsencode`, read back by
        :func:`hil.cli._plotter.read_run_dir`): written as text in the locale's encoding, a name that is not
        UTF-8 (``--out $'\\xff'``), or any letter beyond ASCII under a C locale, was a
        ``UnicodeEncodeError``'s traceback after a run that had completed. A process that has already
        ended (killed, out of memory) leaves a closed pipe: that is said by :meth:`wait` (its exit status),
        not a BrokenPipeError's traceback here."""
        stdin = self.process.stdin
        assert isinstance(stdin, io.TextIOWrapper)  # text=True: its binary layer takes the name's bytes
        try:
            stdin.buffer.write(os.fsencode(run_dir) + b"\n")
            stdin.close()
        except BrokenPipeError:
            with contextlib.suppress(BrokenPipeError):
                stdin.close()  # what is left in its buffer goes nowhere: the process is gone

    def wait(self) -> str:
        assert self.process.stderr is not None
        err = self.process.stderr.read()  # to its end: the process has exited then
        self.process.stderr.close()
        self.process.wait()
        if self.process.returncode == 0:
            return ""
        if err.strip():
            return err.strip().splitlines()[-1]
        status = self.process.returncode
        if status < 0:  # a signal ended it (killed, out of memory): named, not a negative "exit status"
            try:
                name = signal.Signals(-status).name
            except ValueError:  # a real-time signal has no name of its own
                name = f"signal {-status}"
            return f"plots: the drawing process was ended by {name}"
        return f"plots: exit status {status}"

    def cancel(self) -> None:
        """Nothing to draw (the run failed, or an interrupt came after it): the process ends, with the
        processes it forked to draw (:mod:`hil.plots.forked`: its process group, its own session's), so none
        is left drawing after ``hil`` exits."""
        if self.process.returncode is None:  # not reaped yet: its pid (the group's id) is still its own
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.process.pid, signal.SIGKILL)  # the group outlives its leader while forks draw
        self.process.wait()
        if self.process.stdin is not None:
            self.process.stdin.close()
        if self.process.stderr is not None:
            self.process.stderr.close()


def start_station(bind: str):  # type: ignore[no-untyped-def]
    """A live ground station on ``bind`` (``--gcs``), its URL printed to stderr."""
    from hil.gcs import GroundStation

    station = GroundStation.live(bind=bind or None)
    print(f"ground station: {station.url}", file=sys.stderr)
    if not station.loopback:
        print(
            f"ground station: listening on {station.host}, not only this machine: anyone who reaches it "
            "with the token can command the board",
            file=sys.stderr,
        )
    sys.stderr.flush()
    return station


def draw_plots(run_dir: Path) -> None:
    """The run directory's plots (``plots/``), as ``hil report`` redraws them, in this process."""
    from hil.plots.run import plot_run

    plot_run(run_dir)


UNREADABLE = "unreadable"
"""How the printed summary shows a value of a type no run writes (a summary.json hil did not write)."""


def format_summary(s: dict) -> str:  # type: ignore[type-arg]
    """The figures a user looks at first, one per line. A figure the run never measured — absent or null: a
    run that failed before its first row (a port that could not be opened) writes none of them — is ``-``
    or "not reached", never a zero: its counts once read 0 failsafe events, its limits ``None``. A value of
    a type no run writes (``true`` for a rate, a negative count, a number for ``exit``) is
    :data:`UNREADABLE`, named on a last line, never printed as a figure (``true`` once read 1.000 rad/s)."""
    return checked_summary(s)[0]


def checked_summary(s: dict) -> tuple[str, list[str]]:  # type: ignore[type-arg]
    """:func:`format_summary`'s text, and each value in it shown as :data:`UNREADABLE` (``KEY is VALUE,
    not ...``; empty for a summary a run wrote): ``hil report`` says a summary with any damaged."""
    f = _Figures(s)
    rmse = f.number("estimator_rmse_deg", ".2f", " deg")
    rmse_note = (
        "(not measured)"
        if "estimator_rmse_deg" not in s
        else "(no ground truth in this run)"  # a run without ground truth writes null
        if s["estimator_rmse_deg"] is None
        else ""
        if rmse == UNREADABLE
        else "(slew + hold)"
    )
    lines = [
        f"exit              {f.text('exit')}  ({f.text('mode')}, {f.number('sim_s', '.1f', ' s')} simulated "
        f"in {f.number('wall_s', '.1f', ' s')}, x{f.number('realtime_factor', '.2f')})",
        f"settle time       {f.number('settle_s', '.1f', ' s')} to <= "
        f"{f.number('settle_requirement_deg', 'g', ' deg')} ({f.verdict('settled')})",
        f"final error       {f.number('final_error_deg', '.3f', ' deg')}",
        f"peak gimbal rate  {f.number('peak_gimbal_rate', '.3f', ' rad/s')} "
        f"(limit {f.number('max_gimbal_rate_limit', 'g', ' rad/s')})",
        f"minimum delta     {f.number('min_delta', '.3f', signed=True)} (singularity measure det(D1 D1ᵀ)/h̄⁶ "
        "of the gimbal array: 0 is singular, the paper's δ)",
        f"estimator RMSE    {rmse} {rmse_note}".rstrip(),
        f"failsafe events   {f.count('failsafe_events')}  resets {f.count('board_resets')}  "
        f"re-arms {f.count('rearms')}",
        f"link              lost {f.count('link_lost')}  reconnects {f.count('reconnects')}  "
        f"stale {f.count('stale_episodes')}  phone gaps {f.count('phone_gaps')}",
    ]
    lines += requirement_lines(s)
    lines += final_disarm_lines(s)
    lines += phone_lines(s)
    lines += operator_lines(s)
    lines += fault_lines(s)
    control = s.get("tasks", {}).get("control")
    if control and s.get("mode") != "lockstep":
        lines.append(
            f"control jitter    p50 {control['lateness_p50_us']:.0f} us  "
            f"p99 {control['lateness_p99_us']:.0f} us  max {control['lateness_max_us']:.0f} us"
        )
    if f.unreadable:
        lines.append(
            f"summary.json damaged (values no run writes, shown as {UNREADABLE}): " + "; ".join(f.unreadable)
        )
    return "\n".join(lines), f.unreadable


class _Figures:
    """A summary's values as :func:`format_summary` prints them: each checked against what a run writes
    for it, ``-`` where it has none (absent or null: never measured), :data:`UNREADABLE` where it is not
    such a value, which is named in :attr:`unreadable` (``KEY is VALUE, not ...``)."""

    def __init__(self, s: dict) -> None:  # type: ignore[type-arg]
        self.s = s
        self.unreadable: list[str] = []

    def _bad(self, key: str, value: object, want: str) -> str:
        self.unreadable.append(f"{key} is {json.dumps(value, default=str)[:40]}, not {want}")
        return UNREADABLE

    def number(self, key: str, fmt: str, unit: str = "", signed: bool = False) -> str:
        """A figure: a finite number, not a bool (JSON's ``true`` is Python's 1), at least 0 unless
        ``signed`` (every figure printed is a time, an angle, a rate's magnitude or a ratio of them but
        δ, a determinant that rounding can take a hair below 0)."""
        value = self.s.get(key)
        if value is None:
            return "-"
        x = finite_number(value)
        if x is None or (x < 0 and not signed):
            return self._bad(key, value, "a number" if signed else "a number >= 0")
        return f"{x:{fmt}}{unit}"

    def count(self, key: str) -> str:
        """A count: an integer >= 0 (not a bool, not 2.0: a run writes its counts as integers)."""
        value = self.s.get(key)
        if value is None:
            return "-"
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            return self._bad(key, value, "a count")
        return str(value)

    def text(self, key: str) -> str:
        value = self.s.get(key)
        if value is None:
            return "-"
        return value if isinstance(value, str) else self._bad(key, value, "a text")

    def verdict(self, key: str) -> str:
        """A requirement's verdict: ``true`` met, ``false`` not, absent or null not reached (a run that
        ended before its slew has no verdict, not a failed one); anything else (the string "false", read as
        met by its truth once) unreadable."""
        value = self.s.get(key)
        if value is None:
            return "not reached"
        if isinstance(value, bool):
            return "met" if value else "NOT met"
        return self._bad(key, value, "true or false")


REQUIREMENT_SHOWN = 400
"""Characters of a missed requirement's reasons the summary shows (summary.json holds them whole)."""


def requirement_lines(s: dict) -> list[str]:  # type: ignore[type-arg]
    """Why the run missed its pointing requirement, when it did (``requirement.why``: the operator, the
    faults, the link, a recovery too late — or nothing in the record: the controller did not settle). The
    settle line says "NOT met"; before, what explains it was in summary.json alone, and a run that ended
    far off its target printed ``exit completed`` and no word of why."""
    req = s.get("requirement")
    if not isinstance(req, dict) or req.get("met") is not False or not isinstance(req.get("why"), str):
        return []
    why = req["why"]
    if len(why) > REQUIREMENT_SHOWN:
        why = why[:REQUIREMENT_SHOWN] + "… (summary.json holds the rest)"
    return [f"requirement       NOT met: {why}"]


def final_disarm_lines(s: dict) -> list[str]:  # type: ignore[type-arg]
    """The run's final Disarm, when it failed: the board is not confirmed disarmed (it may be spinning its
    rotors until its own link watchdog fails it safe)."""
    final = s.get("final_disarm")
    if not isinstance(final, dict) or final.get("ok") is not False:
        return []
    state = final.get("state")
    known = f"; last known {state}" if state else ""
    return [
        f"NOT DISARMED      the board is not confirmed disarmed: the final Disarm failed "
        f"({final.get('error')}){known}"
    ]


def phone_lines(s: dict) -> list[str]:  # type: ignore[type-arg]
    """Other phones heard on the phone's port (a live receiver follows one: docs/formats.md), if any: the
    one followed, the others' messages dropped, the hand-overs."""
    phone = s.get("phone")
    if not isinstance(phone, dict) or not (phone.get("other_phones") or phone.get("phone_switches")):
        return []
    return [
        f"phones            following {phone.get('following')}; {phone.get('other_phones', 0)} other(s) "
        f"dropped ({phone.get('other_phone_messages', 0)} messages), "
        f"{phone.get('phone_switches', 0)} hand-over(s)"
    ]


def operator_lines(s: dict) -> list[str]:  # type: ignore[type-arg]
    """The operator's commands (who sent them, when, how each ended) and how long they kept the run
    suspended; the first :data:`MAX_FAULT_LINES`."""
    ops = s.get("operator") or []
    if not ops:
        return []
    words = [
        f"{o['command']} at {o['t']:.1f} s ({o['origin']}, {o['status']})" for o in ops[:MAX_FAULT_LINES]
    ]
    more = f", ... and {len(ops) - MAX_FAULT_LINES} more" if len(ops) > MAX_FAULT_LINES else ""
    lines = [f"operator          {', '.join(words)}{more}"]
    if s.get("suspended_s"):
        lines.append(
            f"suspended         {s['suspended_s']:.1f} s disarmed by the operator (not counted in the run)"
        )
    return lines


def fault_lines(s: dict) -> list[str]:  # type: ignore[type-arg]
    """Each fault (failsafe, reset with its cause, link loss, reconnect, stale telemetry, phone gap) with
    its time, and each outage with how long it lasted; the first :data:`MAX_FAULT_LINES` of each."""
    lines: list[str] = []
    if s.get("lost"):
        lines.append(f"LOST              {s['lost']}")
    faults = s.get("faults") or []
    for f in faults[:MAX_FAULT_LINES]:
        detail = {k: v for k, v in f.items() if k not in ("t", "kind")}
        words = "  ".join(f"{k} {_short(v)}" for k, v in detail.items())
        lines.append(f"  fault  t {f['t']:8.3f} s  {f['kind']:<13} {words}".rstrip())
    more = len(faults) - MAX_FAULT_LINES + int(s.get("faults_not_kept") or 0)
    if more > 0:
        lines.append(f"  ... and {more} more faults (summary.json)")
    for name, key in (("outage", "outages"), ("phone gap", "phone_gap_list")):
        episodes = s.get(key) or []
        for o in episodes[:MAX_FAULT_LINES]:
            end = "not back" if o["end"] is None else f"back at {o['end']:.3f} s"
            lines.append(
                f"  {name:<6} t {o['start']:8.3f} s  for {o['duration_s']:6.2f} s  {end}  "
                f"({', '.join(o['causes'])})"
            )
        if len(episodes) > MAX_FAULT_LINES:
            lines.append(f"  ... and {len(episodes) - MAX_FAULT_LINES} more {name}s (summary.json)")
    return lines


def _short(value: object) -> str:
    """A fault's detail as the printed summary shows it: a float to four significant figures (one decimal
    once said a 0.25 s bound was 0.2, beside a 0.321 s period printed 0.3), a text up to 60 characters."""
    if isinstance(value, float):
        return f"{value:.4g}"
    text = str(value)
    return text if len(text) <= 60 else text[:57] + "..."
