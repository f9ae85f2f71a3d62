"""The host's link to the board: handshake, commands, setpoints, telemetry, reconnection.

::

    from hil.link.board import BoardClient
    with BoardClient("spawn://firmware-sim?units=4") as board:    # connect() on entry
        board.start()                                               # real time: a reader thread
        board.arm()
        board.send_setpoint(ActuatorSetpoint(units=...))            # at the control rate
        for event in board.drain_events(): ...                      # telemetry, logs, state changes
        board.disarm()

Modules: :mod:`.session` (the sans-IO core), :mod:`.config` (``ClientConfig``), :mod:`.transfers`
(calibration uploads and downloads of a session), :mod:`.client` (transport, clock, reader thread,
reconnection), :mod:`.events` (what is reported), :mod:`.stats` (link statistics),
:mod:`.first_handshake` (every tool's first connect, tried again while the port comes back:
``connect_within``).
``docs/runtime-link.md`` is the guide.
"""

from .client import BoardClient
from .config import HOST_IDENTITY, ClientConfig
from .events import (
    BoardInfo,
    BoardResetEvent,
    CommandEvent,
    ConnectedEvent,
    EscCalibrationEvent,
    Event,
    LinkLostEvent,
    LogEvent,
    SilenceEvent,
    StateEvent,
    TelemetryEvent,
)
from .first_handshake import ConnectRetry, connect_within
from .session import Phase, Session
from .stats import LinkStats, RoundTrips
from .transfers import Download

__all__ = [
    "HOST_IDENTITY",
    "BoardClient",
    "BoardInfo",
    "BoardResetEvent",
    "ClientConfig",
    "CommandEvent",
    "ConnectRetry",
    "ConnectedEvent",
    "Download",
    "EscCalibrationEvent",
    "Event",
    "LinkLostEvent",
    "LinkStats",
    "LogEvent",
    "Phase",
    "RoundTrips",
    "Session",
    "SilenceEvent",
    "StateEvent",
    "TelemetryEvent",
    "connect_within",
]
