"""The emulated ADK board as a sans-IO core: bytes in (``feed``), time passes (``step``), bytes out
(``take_output``). The same object runs behind a pseudo-terminal (:mod:`firmware_sim.servers.pty_server`),
in-process in lockstep, or under fault injection.

Time. The board keeps its own time in integer microseconds on the injected clock's time base and
wakes only when something is due: a main-loop tick with received bytes, a pulse frame, the power
manager's sample, telemetry, a heartbeat, a watchdog deadline. ``step(now)`` runs every wake-up with a
time ≤ ``now`` *at its own scheduled time*, so a late caller (a busy host, a lockstep driver taking big
steps) changes nothing the board does, only when the bytes leave. Everything the board reports —
``Telemetry.time_ms``, the pulse timeline, the reset log — is on this board time, which is what
timing tests measure.

Parts, one job per module:

* :mod:`.core` — :class:`Board`: scheduling, MCU phases (reset, boot, hang and watchdog), the hardware
  that always runs (pulse timers, motors, battery), the public API;
* :mod:`.commands` — the protocol state machine in the main loop: handshake, arming, failsafe on link
  loss, modes, setpoints, ACK/NACK;
* :mod:`.outputs` — pulse widths from commands and calibrations, the LIMIT cap, the PPM train;
* :mod:`.power` — battery and UBEC solved against the loads, the staged power manager, load shedding;
* :mod:`.dead_esc` — outputs that do not respond; :mod:`.calibration` — calibration upload/download;
* :mod:`.telemetry` — the messages it sends (``Log``, ``Telemetry``, ``HelloReply``, fault flags);
* :mod:`.codes` — :class:`McuPhase` and :class:`LogCode`.

The board's hardware and the firmware's building blocks, which those use:

* :mod:`.state` — the board's state machine as a pure transition function;
* :mod:`.link` — the UART ring, framing and the duplicate filter;
* :mod:`.periodic` — exact periodic schedules in integer microseconds;
* :mod:`.power_models` — the battery, the UBEC rail and the staged thresholds;
* :mod:`.actuators` and :mod:`.esc` — the ESC/motor and gimbal-servo response, the ESC's endpoints;
* :mod:`.timeline` — the record of pulse frames and resets;
* :mod:`.faults` — fault injection (link, MCU, battery, ESCs, the phone);
* :mod:`.config` — the board's parameters.

Board time vs. uptime. ``Telemetry.time_ms`` and board ``Heartbeat.time_ms`` are the MCU's uptime:
milliseconds since its last reset (like ``millis()``); :attr:`Board.resets` records each reset on the
board clock, so ``uptime = t − resets[-1].t``.
"""

from .codes import LogCode, McuPhase
from .core import Board

__all__ = ["Board", "LogCode", "McuPhase"]
