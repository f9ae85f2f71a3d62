"""The built-in emulator forms of a board: in-process (``emu://``) and a spawned ``firmware-sim`` (``spawn://``).

Both take the options of ``firmware-sim`` in the query string, spelled as on its command line without the
dashes (``frame_rate`` or ``frame-rate`` for ``--frame-rate``; a flag is ``ppm=1``; a repeatable fault is
repeated: ``stall=5:2&stall=9:1``)::

    emu://?units=4                          an in-process board on the host's clock
    emu://?units=4&board=firmware           ... the real firmware under simavr, stepped on that clock
    emu://?units=3&frame_rate=400&stall=5:2 ... with a link stall at t = 5 s
    spawn://firmware-sim?units=4            firmware-sim started on a pty, stopped on close
    spawn://firmware-sim?corrupt=0.01&link=/tmp/board&start_timeout=20
    spawn://firmware-sim?board=firmware&usb=1&world=cubesat-1u   the firmware's USB link driving a world

**In-process** (:class:`EmulatorTransport`). The :class:`firmware_sim.board.Board` runs on the clock it is
given (``clock=`` or :meth:`EmulatorTransport.bind_clock`, which :class:`hil.link.board.BoardClient` calls
with
its own clock; a plain WallClock otherwise). With a ``LockstepClock`` every write feeds the board at the
clock's time and every read steps it to the clock's time and returns what it sent — a read never waits,
since simulated time moves only when its owner advances it — so a closed loop through the full protocol
runs as fast as the CPU allows and replays exactly. With any other clock the board behaves as a real-time
board: a read waits (up to its timeout) until the board's next wake-up produces bytes. The board is
:attr:`EmulatorTransport.board`, for the world simulation (``Board.set_unit_states``, the pulse timeline,
``board.faults``); in real time, touch it only inside ``with transport.lock:``.

``board`` chooses the board: ``emulator`` (the Python emulator, :class:`firmware_sim.board.Board`, the
default) or ``firmware`` (the firmware ELF under simavr, :class:`firmware_sim.avr.stepped.FirmwareBoard`:
deterministic in lockstep, its pulses driving the same world; ``spawn://`` runs ``firmware-sim --avr``).

**Spawned** (:class:`SpawnTransport`). Runs ``sys.executable -m firmware_sim`` with the options, reads the
pty path from its first stdout line and opens it with :class:`SerialTransport`. The process is in its own
process group, which :meth:`close` terminates (SIGTERM, then SIGKILL after 3 s); if the host dies
without closing — even by SIGKILL — the kernel sends the child SIGTERM (Linux ``PR_SET_PDEATHSIG``,
armed in the child before it execs firmware-sim, for a parent thread that lives as long as the host).
Its stderr goes to a temporary file, quoted in the error if it fails to start. If the process dies, reads
raise ``LinkError`` like any vanished port; reopening the transport starts a new one.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import select
import signal
import sys
import threading
import time
from typing import IO, TYPE_CHECKING, Any, NoReturn
from urllib.parse import parse_qsl, urlsplit

from hil.link.transports.base import Transport
from hil.link.transports.in_process import InProcessBoard, PulseRecord, SimulatedWorld, WorldStream
from hil.link.transports.serial_port import SerialTransport
from hil.timing.clock import Clock, LockstepClock, WallClock
from protocol.errors import TransportError, TransportRefused

if TYPE_CHECKING:  # subprocess, tempfile and concurrent.futures are imported where a spawn uses them:
    # not by every run of the built-in emulator, which imports this module too (~5 ms of its start)
    import concurrent.futures
    import subprocess

    from firmware_sim.avr.stepped import FirmwareBoard
    from firmware_sim.board import Board

DEFAULT_START_TIMEOUT_S = 10.0
MAX_START_TIMEOUT_S = 3600.0
"""The longest ``start_timeout`` a ``spawn://`` URL may ask for (s): an hour is far beyond any start-up."""
_TERMINATE_GRACE_S = 3.0
EXIT_USAGE = 2
"""firmware-sim's exit status for a usage error: an option or a value it refuses (argparse's)."""

_PROCESS_ONLY = frozenset({"link", "duration", "avr", "eeprom", "no_hold", "verbose", "world", "phone"})
"""firmware-sim options that only make sense for a separate process (a pty, a wall-clock run)."""
_NEVER = frozenset({"can", "help"})
"""Options neither form takes: the spawned board is reached through its pty, not a CAN bus."""

BOARDS = ("emulator", "firmware")
"""The boards an ``emu://`` or ``spawn://`` URL may choose with ``board=``."""

_TRUE = ("", "1", "true", "yes", "on")
_FALSE = ("0", "false", "no", "off")


def firmware_sim_argv(
    url: str, options: list[tuple[str, str]], refused: frozenset[str] = frozenset()
) -> list[str]:
    """The ``firmware-sim`` command line that ``options`` (the URL's query, in order) spell, checked by
    firmware-sim's own parser.

    Raises :class:`TransportError` naming the URL for an option firmware-sim does not have, one in
    ``refused``, a bad value, or a flag whose value is not a boolean."""
    from firmware_sim.cli import build_parser

    parser = build_parser()
    flags = {a.dest for a in parser._actions if a.nargs == 0}  # store_true / count options
    repeatable = {a.dest for a in parser._actions if isinstance(a, argparse._AppendAction)}
    argv: list[str] = []
    seen: set[str] = set()
    for key, value in options:
        name = key.replace("-", "_")
        if name in refused or name in _NEVER:
            raise TransportError(f"{url}: option {key!r} is not available here")
        if name in seen and name not in repeatable:  # argparse would keep the last, silently
            raise TransportError(f"{url}: option {key!r} is given twice (only the faults repeat)")
        seen.add(name)
        option = "--" + name.replace("_", "-")
        if name in flags:
            if value.lower() in _TRUE:
                argv.append(option)
            elif value.lower() not in _FALSE:
                raise TransportError(f"{url}: option {key}={value!r} is not a boolean")
        else:
            argv.append(f"{option}={value}")  # "-5:-1" stays the option's value, not another option
    _parse(parser, argv, url)
    return argv


def split_board(url: str, options: list[tuple[str, str]]) -> tuple[str, list[tuple[str, str]]]:
    """The ``board`` option (default ``emulator``) and the other options, in order. Given twice it is
    refused, as firmware-sim's own options are (:func:`firmware_sim_argv`): the last one silently won."""
    boards = [v for k, v in options if k == "board"]
    if len(boards) > 1:
        raise TransportRefused(f"{url}: option 'board' is given {len(boards)} times")
    board = boards[0] if boards else "emulator"
    if board not in BOARDS:
        raise TransportRefused(f"{url}: board={board!r} is not one of {', '.join(BOARDS)}")
    return board, [(k, v) for k, v in options if k != "board"]


def start_timeout(url: str, values: list[str]) -> float:
    """A ``spawn://`` URL's ``start_timeout`` (its ``values``, in order; none: the default): one finite
    number of seconds in (0, :data:`MAX_START_TIMEOUT_S`], else a :class:`TransportRefused` naming the
    option. A wait as long as 1e308 s overflowed ``select`` (a traceback), and NaN or a negative one timed
    out at once, each start failing in turn until the run's outage bound ran out."""
    if not values:
        return DEFAULT_START_TIMEOUT_S
    if len(values) > 1:
        raise TransportRefused(f"{url}: option 'start_timeout' is given {len(values)} times")
    try:
        value = float(values[0])
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and 0.0 < value <= MAX_START_TIMEOUT_S):
        raise TransportRefused(
            f"{url}: option start_timeout={values[0][:40]!r} must be a number of seconds in "
            f"(0, {MAX_START_TIMEOUT_S:g}]"
        )
    return value


def _parse(parser: argparse.ArgumentParser, argv: list[str], url: str) -> argparse.Namespace:
    def refuse(message: str) -> NoReturn:
        raise TransportError(f"{url}: {message}")

    parser.error = refuse  # type: ignore[method-assign]  # a typed error instead of printing and exiting
    parser.allow_abbrev = False  # "frame_rat" is a typo here, not --frame-rate
    return parser.parse_args(argv)


# =========================================================================== in-process
class EmulatorTransport(InProcessBoard):
    """An in-process emulated board; see the module docstring. ``clock`` None: bound later by
    :meth:`bind_clock` (the board client does), else a WallClock at first use."""

    scheme = "emu"

    def __init__(self, url: str = "emu://", clock: Clock | None = None) -> None:
        super().__init__(url)
        parts = urlsplit(url)
        if parts.netloc or parts.path.strip("/"):
            raise TransportError(f"{url}: the in-process emulator takes only options (emu://?units=4&...)")
        self.board_kind, options = split_board(url, parse_qsl(parts.query, keep_blank_values=True))
        self._argv = firmware_sim_argv(url, options, _PROCESS_ONLY)
        self._clock = clock
        self._board: Board | FirmwareBoard | None = None
        self.lock = threading.Condition(threading.RLock())

    @property
    def clock(self) -> Clock | None:
        """The clock the board runs on (None until bound or first used)."""
        return self._clock

    def bind_clock(self, clock: Clock) -> None:
        """Run the board on ``clock`` (before the board exists); binding the clock it already has is a
        no-op, another one raises :class:`TransportError`."""
        if self._clock is not None and self._clock is not clock:
            raise TransportError(f"{self.url}: the emulated board already runs on another clock")
        self._clock = clock

    @property
    def board(self) -> Board | FirmwareBoard:
        """The emulated board (created on first use, on the bound clock)."""
        if self._board is None:
            from firmware_sim.cli import build_parser, make_board

            if self._clock is None:
                self._clock = WallClock()
            args = _parse(build_parser(), self._argv, self.url)
            if self.board_kind == "firmware":
                from firmware_sim.avr.stepped import firmware_board

                self._board = firmware_board(args, self._clock)
            else:
                self._board = make_board(args, self._clock)
        return self._board

    @property
    def realtime(self) -> bool:
        """False on a LockstepClock: reads never wait, time moves only when its owner advances it."""
        return not isinstance(self.clock, LockstepClock)

    def next_wake(self) -> float:
        """Clock time (s) at which the board next does something (a lockstep driver advances to it)."""
        with self.lock:
            return self.board.next_deadline()

    def pulse_record(self, since: int) -> PulseRecord:
        with self.lock:
            board = self.board
            frames, missed = board.timeline.since(since)
            count = board.timeline.total_frames
            cfg = board.config
        rotors = tuple(range(1, cfg.n_channels, 2))  # channel 2i: unit i's gimbal servo, 2i + 1 its rotor ESC
        return PulseRecord(
            [(f.t, f.widths, f.state) for f in frames], count, missed, rotors, float(cfg.rotor_safe_us)
        )

    def open_world(self, scenario: Any, seed: int | None = None) -> SimulatedWorld:
        """The scenario's world (:class:`firmware_sim.world.World`) on this board."""
        from firmware_sim.world import World

        with self.lock:
            return World(scenario, self.board, seed=seed)

    def stream_world(self, world: SimulatedWorld, phone_url: str) -> WorldStream:
        """The world stepped in real time by its own thread (:class:`firmware_sim.world.WorldStreamer`),
        streaming its phone to ``phone_url``."""
        from firmware_sim.world import World, WorldStreamer

        assert isinstance(world, World)
        with self.lock:
            world.prepare()  # its first batch stepped before its thread's first pass
        return WorldStreamer(world, self.lock, phone_url).start()

    # ------------------------------------------------------------------ backend
    def _open_impl(self) -> None:
        board = self.board  # the board powers up with the first connection and keeps running across reopens
        with self.lock:
            board.step()
            self._check_plugged(board)

    def _check_plugged(self, board: Board | FirmwareBoard) -> None:
        """A board whose cable is out (``unplug`` fault) has no port: it vanished, as a USB device does."""
        if board.unplugged():
            raise TransportError(f"{self.url}: the port vanished (the board's cable is out: unplug fault)")

    def _read(self, timeout: float | None) -> bytes:
        board, clock = self.board, self.board.clock
        with self.lock:
            board.step()
            self._check_plugged(board)
            out = board.take_output()
            if out or not self.realtime or timeout == 0:
                return out
            end = None if timeout is None else clock.now() + timeout
            while True:
                now = clock.now()
                if end is not None and now >= end:
                    return b""
                wait = board.next_deadline() - now
                if end is not None:
                    wait = min(wait, end - now)
                self.lock.wait(max(wait, 0.0))
                board.step()
                out = board.take_output()
                if out:
                    return out

    def _write(self, data: bytes) -> None:
        with self.lock:
            self.board.step()
            self._check_plugged(self.board)
            self.board.feed(data)
            self.lock.notify_all()  # a reader waiting for the board's next wake-up: it comes sooner

    def _close(self) -> None:
        pass  # the cable is unplugged; the board keeps its state (its link watchdog will notice)


# =========================================================================== spawned firmware-sim
_GUARD = """\
import ctypes, os, signal, sys
try:
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
except (OSError, AttributeError):
    pass  # not Linux: only close() stops the process group
if os.getppid() != int(sys.argv[1]):
    sys.exit(0)  # the host died before the death signal was armed
os.execv(sys.executable, [sys.executable, "-m", "firmware_sim", *sys.argv[2:]])
"""
"""Runs in the child before firmware-sim: arms the parent-death signal, then execs ``-m firmware_sim``."""

_spawner: concurrent.futures.ThreadPoolExecutor | None = None
_spawner_lock = threading.Lock()


def _spawn(argv: list[str], stderr: IO[bytes]) -> subprocess.Popen[bytes]:
    """Start ``argv`` from one long-lived thread: the parent-death signal fires when the *thread* that
    forked the child exits, so forking from a reader thread that later stops would kill the board."""
    import concurrent.futures
    import subprocess

    global _spawner
    with _spawner_lock:
        if _spawner is None:
            _spawner = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="hil-spawn")
        spawner = _spawner
    future = spawner.submit(
        subprocess.Popen,
        argv,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=stderr,
        start_new_session=True,  # its own process group: close() ends it and anything it started
    )
    return future.result()


class SpawnTransport(Transport):
    """``firmware-sim`` started on a pty for this connection; see the module docstring."""

    scheme = "spawn"

    def __init__(self, url: str) -> None:
        super().__init__(url)
        parts = urlsplit(url)
        if parts.netloc != "firmware-sim" or parts.path.strip("/"):
            raise TransportError(f"{url}: only spawn://firmware-sim[?options] can be spawned")
        pairs = parse_qsl(parts.query, keep_blank_values=True)
        board, pairs = split_board(url, pairs)
        options = [(k, v) for k, v in pairs if k != "start_timeout"] + (
            [("avr", "")] if board == "firmware" else []
        )
        self.start_timeout = start_timeout(url, [v for k, v in pairs if k == "start_timeout"])
        self.argv = firmware_sim_argv(url, options)
        self.process: subprocess.Popen[bytes] | None = None
        self.device: str | None = None
        self._serial: SerialTransport | None = None
        self._stderr: IO[bytes] | None = None

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid

    def stderr_text(self) -> str:
        """What firmware-sim wrote to stderr so far (its log)."""
        if self._stderr is None:
            return ""
        self._stderr.flush()
        self._stderr.seek(0)
        return self._stderr.read().decode("utf-8", "replace")

    # ------------------------------------------------------------------ backend
    def _open_impl(self) -> None:
        import tempfile

        self._stderr = tempfile.TemporaryFile()
        command = [sys.executable, "-c", _GUARD, str(os.getpid()), *self.argv]
        self.process = _spawn(command, self._stderr)
        try:
            self.device = self._first_line(self.process)
            self._serial = SerialTransport(self.device)
            self._serial.open()
        except BaseException:
            self._stop_process()
            raise

    def _read(self, timeout: float | None) -> bytes:
        assert self._serial is not None
        return self._serial.read(timeout)

    def _write(self, data: bytes) -> None:
        assert self._serial is not None
        self._serial.write(data)

    def _close(self) -> None:
        serial_port, self._serial = self._serial, None
        if serial_port is not None:
            serial_port.close()
        self._stop_process()

    # ------------------------------------------------------------------ internals
    def _first_line(self, process: subprocess.Popen[bytes]) -> str:
        """The pty path firmware-sim prints first; TransportError (quoting its stderr) if it exits or
        stays silent for ``start_timeout`` s."""
        assert process.stdout is not None
        fd = process.stdout.fileno()
        line = b""
        end = time.monotonic() + self.start_timeout
        while b"\n" not in line:
            remaining = end - time.monotonic()
            if remaining <= 0:
                raise TransportError(
                    f"{self.url}: firmware-sim printed no pty path within "
                    f"{self.start_timeout:g} s{self._stderr_tail()}"
                )
            ready, _, _ = select.select([fd], [], [], remaining)
            if not ready:
                continue
            chunk = os.read(fd, 4096)
            if not chunk:
                process.wait(timeout=_TERMINATE_GRACE_S)
                # status 2 is its usage error (an option's value): starting it again cannot help
                refused = TransportRefused if process.returncode == EXIT_USAGE else TransportError
                raise refused(
                    f"{self.url}: firmware-sim exited with status {process.returncode} "
                    f"before it was ready{self._stderr_tail()}"
                )
            line += chunk
        path = line.split(b"\n", 1)[0].decode("utf-8", "replace").strip()
        if not path.startswith("/"):
            raise TransportError(f"{self.url}: firmware-sim's first line is not a pty path: {path!r}")
        return path

    def _stderr_tail(self, lines: int = 5) -> str:
        text = self.stderr_text().strip()
        return ": " + " | ".join(text.splitlines()[-lines:]) if text else ""

    def _stop_process(self) -> None:
        process, self.process = self.process, None
        if process is not None:
            _terminate_group(process)
            if process.stdout is not None:
                process.stdout.close()
        stderr, self._stderr = self._stderr, None
        if stderr is not None:
            stderr.close()


def _terminate_group(process: subprocess.Popen[Any]) -> None:
    """SIGTERM to the process group (firmware-sim exits cleanly on it), SIGKILL if it lingers."""
    import subprocess

    for sig in (signal.SIGTERM, signal.SIGKILL):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, sig)
        try:
            process.wait(timeout=_TERMINATE_GRACE_S)
            return
        except subprocess.TimeoutExpired:
            continue
