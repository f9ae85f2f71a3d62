"""The simulated phone of the in-process board's world as a run's phone (``sim://``).

The built-in emulator (``emu://``) carries a simulated world (:class:`~hil.link.transports.SimulatedWorld`:
spacecraft, VSCMG plant, the phone on the body) that its pulses drive; ``hil run`` without ``--port`` takes
its phone from there. How the samples travel depends on the run's clock:

- **lockstep**: the world is stepped on the run's scheduler (a ``world`` task every plant step, or every
  ``advance_period_s`` when the world keeps the board current over a longer span) and before each
  estimator and control activation, and its samples are handed over in this process
  (:class:`WorldPhone`);
- **real time** (``hil run --realtime``): the world runs in its own thread and streams its phone over UDP
  on loopback to a receiver, the way the SensaGram app streams (:class:`StreamedWorldPhone`), so the live
  path a real phone takes is exercised for real.

Either way the world's own motion is the truth. The world (and with it this adapter) belongs to the far
side: the scheme is registered by entry point only (``vscmg_hil.phone_sources``), so moving the world
under ``firmware_sim`` moves this one line of ``pyproject.toml`` with it.
"""

from __future__ import annotations

import contextlib
import sys
from typing import TYPE_CHECKING, Any

from hil.link.sources.base import GroundTruth, PhoneSource, SenderStatus, SourceContext
from hil.link.sources.listening import listen
from hil.link.transports import InProcessBoard
from hil.timing.scheduler import PeriodicTask
from protocol.errors import ConfigError

if TYPE_CHECKING:
    import threading

    from hil.estimation.sensors import SensorSample
    from hil.link.transports import SimulatedWorld
    from hil.timing.clock import Clock

SIMULATED_URL = "sim://"
"""The URL of the built-in emulator's simulated phone (``hil run`` without ``--port``)."""
LOOPBACK_URL = "udp://127.0.0.1:0"
"""Where a real-time run's world streams its phone: a free UDP port on loopback."""
SWITCH_INTERVAL_S = 5e-4
"""The interpreter hands the GIL over this often (s) while the world's thread runs beside the control
thread (Python's default is 5 ms), so a control deadline waits at most this long for it."""


def simulated_phone(url: str, context: SourceContext) -> PhoneSource:
    """The ``sim://`` source: the in-process board's world, stepped in lockstep or streaming in real time
    (the run's clock decides). Any other board is a :class:`ConfigError`: a real board has no world."""
    board = context.board
    if not isinstance(board, InProcessBoard):
        raise ConfigError(
            f"{url}: the simulated phone is the built-in emulator's (emu://), not {board.url}'s", "--phone"
        )
    if context.lockstep:
        world = board.open_world(context.scenario)
        period = float(getattr(world, "advance_period_s", None) or context.scenario.loop.plant_step_s)
        return WorldPhone(url, world, board.lock, context.clock, period)
    return StreamedWorldPhone(url, board, context)


class WorldPhone(PhoneSource):
    """A lockstep world's phone, handed over in this process: the world is brought to the clock's present
    every ``step_period_s`` (s) by the ``world`` task, before the board is serviced, and before each drain,
    so whatever the order of tasks due together the host sees the world of its instant."""

    def __init__(
        self,
        url: str,
        world: SimulatedWorld,
        lock: threading.Condition,
        clock: Clock,
        step_period_s: float,
    ) -> None:
        self.url = url
        self.world = world
        self._lock = lock
        self._clock = clock
        self._step_period_s = step_period_s
        self._pending: list[SensorSample] = []

    def advance(self, now: float) -> None:
        """The world to ``now``: plant steps, pulse frames, and the phone samples taken meanwhile."""
        self._pending.extend(self.world.advance_to(now))

    def tasks(self) -> list[PeriodicTask]:
        # Every plant step, so the board's telemetry and power draw see the units of the present step
        # (World.advance_to hands the board their states once per call: called every 5 ms instead, the
        # reported rotor speeds lag by up to that and the pulse-quantised hold loses about half a degree),
        # unless the world says it keeps the board current over a longer span (SimulatedWorld).
        clock = self._clock
        return [PeriodicTask("world", self._step_period_s, lambda _due: self.advance(clock.now()))]

    def drain(self, now: float) -> list[SensorSample]:
        self.advance(now)
        out = self._pending.copy()
        self._pending.clear()
        return out

    def truth(self, now: float) -> GroundTruth:
        """The world's attitude and rate now (the world is at the clock's present)."""
        return _world_truth(self.world, self._lock)

    def close(self) -> None:
        """Nothing to release: the world is the board's, closed with the board's link."""


class StreamedWorldPhone(PhoneSource):
    """A real-time world streaming its phone over UDP on loopback to a receiver of this run: the world
    steps in its own thread (the board's ``stream_world``), the samples come in through the live path. The
    world thread's error is raised from :meth:`drain`; ``events.jsonl`` gets ``phone_listening`` when the
    receiver is up and ``world_end`` (the furthest the world fell behind the board's clock) at the close."""

    def __init__(self, url: str, board: InProcessBoard, context: SourceContext) -> None:
        self.url = url
        self._lock = board.lock
        self._closing = contextlib.ExitStack()
        try:
            self.receiver = self._closing.enter_context(listen(LOOPBACK_URL, context))
            self.world = board.open_world(context.scenario)
            # The world thread shares this interpreter: hand the GIL over often, so that a control
            # deadline is not kept waiting for it.
            self._closing.callback(sys.setswitchinterval, sys.getswitchinterval())
            sys.setswitchinterval(SWITCH_INTERVAL_S)
            streamer = board.stream_world(self.world, self.receiver.url)
            self.streamer = streamer
            self._closing.callback(streamer.close)
            clock, write_event = context.clock, context.write_event
            self._closing.callback(
                lambda: write_event(clock.now(), "world_end", max_lag_ms=streamer.max_lag_s * 1e3)
            )
        except BaseException:
            self._closing.close()
            raise

    def drain(self, now: float) -> list[SensorSample]:
        self.streamer.check()  # the world thread's error, raised here
        return self.receiver.drain(now)

    def truth(self, now: float) -> GroundTruth:
        """The world's attitude and rate as its thread last left them."""
        return _world_truth(self.world, self._lock)

    def close(self) -> None:
        """``world_end`` written, the world thread stopped, the GIL's interval restored, the receiver
        closed: the reverse of the opening."""
        self._closing.close()

    def senders(self) -> SenderStatus | None:
        """Its receiver's: another phone may stream to the loopback port too."""
        return self.receiver.senders()

    def report(self) -> dict[str, dict[str, Any]]:
        return self.receiver.report()


def _world_truth(world: SimulatedWorld, lock: threading.Condition) -> GroundTruth:
    """The world's truth read under the board's lock (a world thread may be stepping it)."""
    with lock:
        now = world.truth()
    return GroundTruth(now.R, now.omega)
