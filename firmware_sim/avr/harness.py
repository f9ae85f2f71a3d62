"""The firmware on an emulated ATmega2560: a running ``avr-harness`` process behind a pseudo-terminal.

:class:`AvrBoard` builds what is missing (``make -C firmware``), writes the board configuration into an
EEPROM image, starts the harness (``firmware/harness``) on the firmware ELF and talks to it over its
control pipe: harness time, fault injection (link noise, the watchdog self-test pin, battery sags, the
reset button) and the record of pulse edges and resets. The host talks to the board itself through
:attr:`AvrBoard.port`, a pty path, exactly as to a real board or to ``firmware-sim``.

Times are the harness's: CPU cycles / 16 MHz since power-on, running on through resets (seconds).
"""

from __future__ import annotations

import contextlib
import os
import queue
import signal
import subprocess
import tempfile
import threading
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import NoReturn

from protocol.calibration import UnitCalibration, default_unit_calibration
from protocol.errors import ConfigError, LinkError, LinkTimeout

from ..board.config import BoardConfig
from ..board.esc import EmulatedEsc, EscParams, replay_esc
from ..board.timeline import PpmTrain, PulseFrame, ResetEvent
from . import eeprom
from .build import ensure_built
from .paths import FIRMWARE_ELF, HARNESS
from .records import RecordReader

F_CPU = 16_000_000
PPM_PIN = 10  # board_pins.h: PPM_PIN_INDEX (OC5B)
STACK_PAINT = 0xC5  # main.c
_START_TIMEOUT_S = 10.0
_ANSWER_TIMEOUT_S = 10.0


@dataclass(frozen=True)
class HarnessOptions:
    """How the harness runs the board (everything except the board configuration itself)."""

    elf: Path = FIRMWARE_ELF
    paced: bool = True  # simulated time follows wall time; False: as fast as the host allows
    link: str | None = None  # keep a symlink here pointing at the pty
    eeprom_file: Path | None = None  # persist the EEPROM here (None: a temporary image)
    battery_v: float = 12.6
    corrupt: float = 0.0
    drop: float = 0.0
    seed: int = 0
    hang_at: tuple[float, ...] = ()
    sags: tuple[tuple[float, float, float, float], ...] = ()  # (volts, at, ramp, duration)
    duration_s: float | None = None
    stepped: bool = False  # time moves only on "step" commands (lockstep: firmware_sim.avr.stepped)
    uart_pipe: bool = False  # UART0 through the control pipe instead of the pty (with stepped)
    usb: bool = False  # a phone on the USB host port, the pty its accessory app; the EEPROM's link = usb
    extra_args: tuple[str, ...] = ()

    @property
    def board_link(self) -> str:
        """The link a new EEPROM image tells the firmware to use (``eeprom.LINKS``)."""
        return "usb" if self.usb else "uart"

    def arguments(self, eeprom_path: Path, record_path: Path | None, control: bool) -> list[str]:
        """The harness's command line. Its stdin is always its lifeline (``--control``: the commands'
        pipe; else ``--lifeline``): the caller must give it a pipe that only the caller holds, so the
        harness stops when the caller dies, however it dies."""
        args = [str(HARNESS), "--eeprom", str(eeprom_path), "--battery", repr(self.battery_v)]
        if record_path is not None:
            args += ["--record", str(record_path)]
        args.append("--control" if control else "--lifeline")
        if not self.paced:
            args.append("--unpaced")
        if self.stepped:
            args.append("--stepped")
        if self.uart_pipe:
            args.append("--uart-pipe")
        if self.usb:
            args.append("--usb")
        if self.link:
            args += ["--link", self.link]
        if self.corrupt or self.drop:
            args += ["--corrupt", repr(self.corrupt), "--drop", repr(self.drop)]
        args += ["--seed", str(self.seed)]
        for t in self.hang_at:
            args += ["--hang-at", repr(t)]
        for volts, at, ramp, duration in self.sags:
            args += [
                "--sag",
                f"{volts!r}@{at!r}/{ramp!r}" + ("" if duration == float("inf") else f":{duration!r}"),
            ]
        if self.duration_s is not None:
            args += ["--duration", repr(self.duration_s)]
        return [*args, *self.extra_args, str(self.elf)]


class HarnessProcess:
    """A running ``avr-harness --control``: the process and its control pipe (commands on its stdin,
    answers on its stdout after the first line, the pty path it serves). The pipe is also its lifeline:
    only this process holds the write end, so however this process ends the harness reads end of file
    and stops cleanly (docs/firmware_sim.md, "Lifetimes").

    It runs in a session of its own: a terminal's Ctrl-C (sent to the foreground process group) reaches
    only the process driving it, which stops it by closing the pipe, so a Ctrl-C is never mistaken for
    the harness dying. ``pass_fds``: descriptors it inherits (an anonymous EEPROM image)."""

    def __init__(self, argv: Sequence[str], pass_fds: Sequence[int] = ()) -> None:
        self._lock = threading.Lock()
        self._proc: subprocess.Popen[str] | None = subprocess.Popen(
            list(argv),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
            pass_fds=tuple(pass_fds),
        )
        self.pid = self._proc.pid
        self.returncode: int | None = None
        """How it ended (``Popen.returncode``) once it has; None while it runs."""
        self._stderr: list[str] = []
        self._lines: queue.Queue[str] = queue.Queue()
        self._owed = 0
        """Answers still to come to commands that timed out (the harness stopped, or not run for a while):
        read and dropped before the next command's, so an answer is never taken for a later command's."""
        self._threads = [
            threading.Thread(target=self._drain_stderr, daemon=True),
            threading.Thread(target=self._read_stdout, daemon=True),
        ]
        for t in self._threads:
            t.start()
        try:
            self.port = self._read_line(_START_TIMEOUT_S, "its pty path")
            if not self.port.startswith("/dev/"):
                raise LinkError(f"avr-harness did not print a pty path: {self.port!r}")
        except BaseException:
            self.close()
            raise

    def _drain_stderr(self) -> None:
        """Keep the harness's last stderr lines (for error messages); ends when the harness exits."""
        proc = self._proc
        if proc is None or proc.stderr is None:
            return
        with proc.stderr:
            for line in proc.stderr:
                self._stderr.append(line.rstrip())
                del self._stderr[:-50]

    def _read_stdout(self) -> None:
        """The harness's stdout, line by line, into a queue (an empty line: it closed its stdout)."""
        proc = self._proc
        if proc is None or proc.stdout is None:
            return
        with proc.stdout:
            for line in proc.stdout:
                self._lines.put(line.strip())
        self._lines.put("")

    def _read_line(self, timeout: float, what: str) -> str:
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            self._died(f"no answer ({what}) within {timeout} s")
        if not line:
            self._died(f"its control pipe closed, no answer ({what})", ended=True)
        return line

    def _died(self, why: str, ended: bool = False) -> NoReturn:
        """Raise what went wrong: :class:`HarnessDied` when the harness has ended (``ended``: its pipes
        closed, so it is reaped first), :class:`LinkTimeout` when it runs but does not answer."""
        proc = self._proc
        code = None if proc is None else proc.poll()
        if code is None and proc is not None and ended:
            with contextlib.suppress(subprocess.TimeoutExpired):
                code = proc.wait(timeout=1.0)
        tail = "\n".join(self._stderr[-10:])
        if proc is not None and code is not None:
            self.returncode = code
            raise HarnessDied(proc.pid, code, "", f"{why}{': ' + tail if tail else ''}", said=tail)
        raise LinkTimeout(f"avr-harness: {why} (still running){': ' + tail if tail else ''}")

    def command(self, line: str) -> list[str]:
        """Send one control command; its answer's words after "ok" (LinkError on "error ..." or death;
        :class:`LinkTimeout` when a harness still running has not answered within ``_ANSWER_TIMEOUT_S``:
        its late answer is dropped when it comes, before the next command's is read)."""
        with self._lock:
            proc = self._proc
            if proc is None or proc.stdin is None:
                raise LinkError("avr-harness is closed")
            while self._owed:  # late answers first: the harness answers its commands in order
                self._read_line(_ANSWER_TIMEOUT_S, f"an earlier command's late answer, before {line!r}")
                self._owed -= 1
            try:
                proc.stdin.write(line + "\n")
                proc.stdin.flush()
            except (BrokenPipeError, OSError):
                self._died(f"control pipe broken on {line!r}", ended=True)
            try:
                answer = self._read_line(_ANSWER_TIMEOUT_S, line)
            except LinkTimeout:
                self._owed += 1
                raise
        words = answer.split()
        if not words or words[0] != "ok":
            raise LinkError(f"avr-harness refused {line!r}: {answer}")
        return words[1:]

    def check(self) -> None:
        """Raise :class:`HarnessDied` if the harness has died (a crashed firmware, a crashed simulator)."""
        proc = self._proc
        if proc is None:
            raise LinkError("avr-harness is closed")
        if proc.poll() is not None:
            self._died("exited")

    def close(self) -> None:
        """Stop it (``quit``, then end of file; killed if it lingers) and reap it. Idempotent."""
        proc, self._proc = self._proc, None
        if proc is not None:
            with contextlib.suppress(OSError, ValueError):
                assert proc.stdin is not None
                proc.stdin.write("quit\n")
                proc.stdin.flush()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            for t in self._threads:
                t.join(timeout=5)
            if proc.stdin is not None:
                with contextlib.suppress(OSError):
                    proc.stdin.close()
            if self.returncode is None:
                self.returncode = proc.returncode


class AvrBoard:
    """One emulated board. Use as a context manager; :meth:`close` is idempotent.

    ``config`` is written into the board's EEPROM configuration block (so ``n_units``, rates, timeouts,
    power thresholds reach the firmware the way they reach a real board); ``calibrations`` (one
    ``UnitCalibration`` or None per unit) into its calibration slots (None: erased slot, the default set).
    ``eeprom_image`` (4096 bytes) replaces all of that with raw EEPROM contents (e.g. a damaged block).
    """

    def __init__(
        self,
        config: BoardConfig | None = None,
        options: HarnessOptions | None = None,
        calibrations: Sequence[UnitCalibration | None] = (),
        eeprom_image: bytes | None = None,
    ) -> None:
        self.config = config if config is not None else BoardConfig()
        self.options = options if options is not None else HarnessOptions()
        eeprom.check_hardware(self.config)
        ensure_built()
        if not self.options.elf.exists():
            raise ConfigError(f"no firmware ELF at {self.options.elf}", "HarnessOptions.elf")
        self._dir = tempfile.TemporaryDirectory(prefix="avr-board-")
        work = Path(self._dir.name)
        self._eeprom_path = self.options.eeprom_file or work / "eeprom.bin"
        if eeprom_image is not None:
            if len(eeprom_image) != eeprom.EEPROM_SIZE:
                raise ConfigError(
                    f"{len(eeprom_image)} bytes, not {eeprom.EEPROM_SIZE}", "AvrBoard.eeprom_image"
                )
            self._eeprom_path.write_bytes(eeprom_image)
        elif self.options.eeprom_file is None or _eeprom_file_to_make(self._eeprom_path):
            sets = tuple(None if c is None else c.to_bytes() for c in calibrations)
            image = eeprom.EepromImage(self.config, sets, link=self.options.board_link)
            self._eeprom_path.write_bytes(image.to_bytes())
        else:
            _check_kept_eeprom(self._eeprom_path, self.config, self.options.board_link)
        self._record_path = work / "record.txt"
        self._record_path.touch()
        self.process = HarnessProcess(
            self.options.arguments(self._eeprom_path, self._record_path, control=True)
        )
        self.port = self.process.port
        n_channels = 2 * self.config.n_units
        self._records = RecordReader(
            self._record_path,
            F_CPU,
            n_channels,
            PPM_PIN if self.config.ppm else None,
            capacity=self.config.timeline_frames,
        )

    # ------------------------------------------------------------------ the control pipe
    def command(self, line: str) -> list[str]:
        """Send one control command; its answer's words after "ok" (LinkError on "error ...", HarnessDied
        when the harness has ended)."""
        return self.process.command(line)

    def check(self) -> None:
        """Raise :class:`HarnessDied` if the harness has died (a crashed firmware, a crashed simulator)."""
        self.process.check()

    def close(self) -> None:
        self.process.close()
        self._dir.cleanup()

    def __enter__(self) -> AvrBoard:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ time and records
    def now(self) -> float:
        """Harness time (s)."""
        return int(self.command("now")[0]) / F_CPU

    def _records_now(self) -> RecordReader:
        self.command("flush")
        self._records.update()
        return self._records

    def timeline(self) -> list[PulseFrame]:
        """Pulse frames measured on the output pins (complete frames only)."""
        return self._records_now().complete_frames()

    def ppm_trains(self) -> list[PpmTrain]:
        return list(self._records_now().ppm)

    def resets(self) -> list[ResetEvent]:
        """Every time the MCU left reset (power-on first), with its cause."""
        return list(self._records_now().resets)

    @property
    def records(self) -> RecordReader:
        return self._records_now()

    def esc(self, unit: int, params: EscParams | None = None) -> EmulatedEsc:
        """An emulated ESC on ``unit``'s rotor channel that has seen every pulse the firmware put on that
        pin, powered through the firmware's ESC supply cut pin (:func:`firmware_sim.board.esc.replay_esc`)."""
        if not 0 <= unit < self.config.n_units:
            raise ConfigError(f"unit {unit} does not exist", "AvrBoard.esc")
        records = self._records_now()
        frames = records.complete_frames()
        return replay_esc(
            frames, 2 * unit + 1, records.esc_supply, params, gap_s=3.0 / self.config.frame_rate_hz
        )

    def eeprom(self) -> bytes:
        """The board's EEPROM as it is now."""
        self.command("eeprom")
        return self._eeprom_path.read_bytes()

    def calibration(self, unit: int) -> UnitCalibration:
        """The calibration set the board's EEPROM holds for ``unit`` (the default set if erased)."""
        if not 0 <= unit < self.config.n_units:
            raise ConfigError(f"unit {unit} does not exist", "AvrBoard.calibration")
        image = self.eeprom()
        data = eeprom.read_calibration(image, self.config.n_units, unit)
        if data is None:
            return default_unit_calibration()
        return UnitCalibration.from_bytes(data, source=f"EEPROM slot {unit}")

    # ------------------------------------------------------------------ faults
    def inject_link_noise(self, corrupt: float, drop: float = 0.0) -> None:
        self.command(f"noise {corrupt!r} {drop!r}")

    def inject_hang(self) -> float:
        """Pull the watchdog self-test pin low: the main loop stops. Returns the harness time (s)."""
        return int(self.command("hang")[0]) / F_CPU

    def inject_sag(self, drop_v: float, ramp_s: float, duration_s: float) -> None:
        self.command(f"sag {drop_v!r} {ramp_s!r} {duration_s!r}")

    def press_reset(self) -> float:
        return int(self.command("reset")[0]) / F_CPU

    def clear_faults(self) -> None:
        self.command("clear")

    def memory(self, address: int, length: int) -> bytes:
        """``length`` bytes of the MCU's data memory (RAM) from ``address``."""
        out = bytearray()
        while length > 0:
            n = min(length, 256)
            out += bytes.fromhex(self.command(f"mem {address} {n}")[0])
            address, length = address + n, length - n
        return bytes(out)

    def watch(self, symbol: str, length: int) -> None:
        """Record the firmware variable ``symbol`` (``length`` bytes of RAM) from now on: its value at every
        rising pulse edge and after every 1 ms slice in which it changed (``records.watched``: harness time
        (s), the bytes)."""
        symbols = _symbols(self.options.elf)
        if symbol not in symbols:
            raise ConfigError(f"no symbol {symbol!r} in {self.options.elf}", "AvrBoard.watch")
        self.command(f"watch {symbols[symbol] & 0xFFFF} {length}")

    def stack_headroom(self) -> int:
        """Bytes of RAM the stack has never reached since reset: the firmware paints the free RAM at
        start-up (main.c) and the paint that is still there is headroom."""
        symbols = _symbols(self.options.elf)
        end, top = symbols["_end"] & 0xFFFF, symbols["__stack"]
        free = self.memory(end, top - end + 1)
        return len(free) - len(free.lstrip(bytes([STACK_PAINT])))

    def link_stats(self) -> dict[str, int]:
        """The bridge's counters: bytes and wire frames each way (as the host sent them, before the
        injected noise), output dropped with no host reading, bytes corrupted and dropped by the noise,
        pacing resets."""
        names: tuple[str, ...] = ("bytes_in", "bytes_out", "dropped_out", "corrupted", "dropped")
        names += ("lag_resets", "frames_in", "frames_out")
        return dict(zip(names, (int(w) for w in self.command("stats")), strict=True))


def _symbols(elf: Path) -> dict[str, int]:
    """Addresses of the ELF's symbols (avr-nm); a :class:`ConfigError` naming ``elf`` when it is none."""
    try:
        done = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True)
    except OSError as exc:
        raise ConfigError(f"cannot run avr-nm on it: {exc.strerror or exc}", str(elf)) from exc
    if done.returncode != 0:
        said = done.stderr.strip().splitlines()[-1] if done.stderr.strip() else f"status {done.returncode}"
        raise ConfigError(f"not an AVR firmware's ELF ({said})", str(elf))
    out = done.stdout
    symbols = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3:
            symbols[parts[2]] = int(parts[0], 16)
    return symbols


class HarnessDied(LinkError):
    """The harness ended without being asked to (killed, crashed, exited): the board it served is gone.
    ``pid`` was its process id, ``returncode`` its ``Popen.returncode`` (negative: the signal)."""

    def __init__(self, pid: int, returncode: int, pty: str, detail: str = "", said: str = "") -> None:
        if detail:  # a stepped harness (no pty of its own): what its driver was doing when it went
            where = f"the board is gone ({detail})"
        else:
            where = f"the board on {pty} is gone" if pty else "before it served a pty"
        super().__init__(f"avr-harness (pid {pid}) {_ending(returncode)}: {where}")
        self.pid, self.returncode = pid, returncode
        self.said = said
        """The harness's last lines on stderr (a crashed firmware's own message), for its driver to show."""


@contextlib.contextmanager
def eeprom_for(options: HarnessOptions, config: BoardConfig) -> Iterator[tuple[Path, tuple[int, ...]]]:
    """The harness's ``--eeprom`` argument and the descriptors it needs passed.

    ``--eeprom FILE``: that file (the image written first if there is none). Otherwise an anonymous
    temporary file, handed over as ``/dev/fd/N``: it has no name, so nothing is left behind however this
    process or the harness ends, SIGKILL included (a temporary directory outlived a killed firmware-sim)."""
    if options.eeprom_file is not None:
        if _eeprom_file_to_make(options.eeprom_file):
            options.eeprom_file.write_bytes(eeprom.EepromImage(config, link=options.board_link).to_bytes())
        else:  # the kept board's configuration wins, but not a link this harness does not serve
            _check_kept_eeprom(options.eeprom_file, config, options.board_link, only=("link",))
        yield options.eeprom_file, ()
        return
    with tempfile.TemporaryFile() as image:
        image.write(eeprom.EepromImage(config, link=options.board_link).to_bytes())
        image.flush()
        yield Path(f"/dev/fd/{image.fileno()}"), (image.fileno(),)


def _eeprom_file_to_make(path: Path) -> bool:
    """Whether ``--eeprom`` ``path`` is to be made (absent, or empty); a :class:`ConfigError` naming it
    when it is no EEPROM image: the harness loads its first 4 KiB and saves the image back over it, so any
    other file given by mistake (a README, a calibration CSV) was cut to 4 KiB and lost, silently; a
    folder was neither loaded nor saved, and a path in a missing folder was a traceback."""
    if not path.exists():
        if not path.parent.is_dir():
            raise ConfigError(f"its folder {str(path.parent)!r} is not there", f"--eeprom {path}")
        return True
    if not path.is_file():
        raise ConfigError("not a regular file: give an EEPROM image's path", f"--eeprom {path}")
    size = path.stat().st_size
    if size not in (0, eeprom.EEPROM_SIZE):
        raise ConfigError(
            f"{size} bytes, not an EEPROM image ({eeprom.EEPROM_SIZE} bytes): left as it is (the board "
            "would overwrite it); give a new file's path, or an image firmware-sim saved",
            f"--eeprom {path}",
        )
    return size == 0


def _check_kept_eeprom(
    path: Path, config: BoardConfig, link: str, only: Collection[str] | None = None
) -> None:
    """A :class:`ConfigError` naming ``--eeprom`` ``path`` when the board kept in it is configured otherwise
    than ``config`` on ``link`` (in the block fields ``only``; None: all that matter): the firmware boots
    on the file's block, while an :class:`AvrBoard` reads its pulse channels, frames and battery from
    ``config``, and the harness serves the host on ``link`` (:func:`.eeprom.config_mismatch`). Refused
    before the harness starts, the file left as it is."""
    differs = eeprom.config_mismatch(path.read_bytes(), config, link, only)
    if differs is not None:
        raise ConfigError(
            f"the board kept in it is configured otherwise: {differs}; give a new file's path, or the "
            "options it was made with",
            f"--eeprom {path}",
        )


def _ending(code: int) -> str:
    """How a process ended, from its ``Popen.returncode``: "killed by SIGKILL", "exited with status 3"."""
    if code >= 0:
        return f"exited with status {code}"
    try:
        return f"killed by {signal.Signals(-code).name}"
    except ValueError:
        return f"killed by signal {-code}"


def remove_link(link: str, pty: str) -> None:
    """Remove the symlink ``link`` if it still points at ``pty`` (anything else there is not ours)."""
    with contextlib.suppress(OSError):
        if os.readlink(link) == pty:
            os.unlink(link)
