"""Transports are URLs resolved by one registry (after pyserial's ``serial_for_url``).

==========================================  ===============================================
URL                                         transport
==========================================  ===============================================
``/dev/pts/N``, ``/dev/ttyACM0``, ``COM3``  serial device (pty, USB CDC, UART adapter)
``socket://``, ``loop://``, ``spy://``,     pyserial URL handlers
``rfc2217://``
``can://<interface>/<channel>?node=N``      a python-can bus (``virtual``, ``udp_multicast``,
                                            ``socketcan``, ...): :mod:`.can_bus`
``emu://?units=4&...``                      the emulated board in-process, on the host's clock
                                            (lockstep or real time): ``firmware_sim.servers.transports``
``spawn://firmware-sim?units=4&...``        ``firmware-sim`` started on a pty for the
                                            connection, stopped on close: ``firmware_sim.servers.transports``
==========================================  ===============================================

Each scheme maps to ``"module:Class"``, imported on first use, so a missing optional backend only
fails when it is asked for. ``open_transport(url)`` returns an opened transport.

Other packages add schemes the way python-can finds its interfaces: an entry point in the group
``vscmg_hil.transports`` whose name is the scheme and whose value is ``"module:factory"`` (the factory
takes the URL and returns an unopened :class:`Transport`). ``firmware_sim`` registers ``emu`` and
``spawn`` so; ``hil`` never imports it. In a ``pyproject.toml``::

    [project.entry-points."vscmg_hil.transports"]
    mybus = "mypackage.transport:MyBusTransport"

:func:`register` adds one at run time.
"""

from __future__ import annotations

from hil.plugins import Registry
from protocol.errors import TransportError

from .base import Transport, UrlOptions
from .in_process import InProcessBoard, SimulatedWorld, WorldStream, WorldTruth

ENTRY_POINT_GROUP = "vscmg_hil.transports"

# scheme -> "module:factory"; the factory takes the URL and returns an unopened Transport.
_REGISTRY = Registry(
    ENTRY_POINT_GROUP,
    {
        "socket": "hil.link.transports.serial_port:SerialTransport",
        "loop": "hil.link.transports.serial_port:SerialTransport",
        "spy": "hil.link.transports.serial_port:SerialTransport",
        "rfc2217": "hil.link.transports.serial_port:SerialTransport",
        "hwgrep": "hil.link.transports.serial_port:SerialTransport",
        "can": "hil.link.transports.can_bus:CanTransport",
    },
)


def register(scheme: str, target: str) -> None:
    """Add (or replace) the transport for ``scheme``; ``target`` is ``"module:factory"``."""
    _REGISTRY.register(scheme, target)


def schemes() -> list[str]:
    return _REGISTRY.names()


def _scheme_of(url: str) -> str:
    if "://" not in url:
        return "serial"  # a device path
    return url.split("://", 1)[0].lower()


def create_transport(url: str) -> Transport:
    """The transport for ``url``, not yet opened."""
    scheme = _scheme_of(url)
    if scheme == "serial":
        from .serial_port import SerialTransport

        return SerialTransport(url)
    target = _REGISTRY.target(scheme)
    if target is None:
        raise TransportError(f"{url}: unknown transport scheme {scheme!r} (known: {', '.join(schemes())})")
    try:
        factory = _REGISTRY.load(target)
    except (ImportError, AttributeError) as exc:
        raise TransportError(f"{url}: transport {target} is not available: {exc}") from exc
    transport: Transport = factory(url)
    return transport


def open_transport(url: str) -> Transport:
    """Resolve ``url`` and open it."""
    return create_transport(url).open()


__all__ = [
    "ENTRY_POINT_GROUP",
    "InProcessBoard",
    "SimulatedWorld",
    "Transport",
    "UrlOptions",
    "WorldStream",
    "WorldTruth",
    "create_transport",
    "open_transport",
    "register",
    "schemes",
]
