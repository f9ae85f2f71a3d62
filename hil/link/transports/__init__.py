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

A scheme that neither ``hil`` nor ``firmware_sim`` ships is held to the interface
(:class:`~.checked.CheckedTransport`): ``read`` must return bytes, and what the transport raises of its
own (not the project's :class:`~protocol.errors.LinkError`, the interface's word for a port that vanished
or cannot open, answered by reconnecting), in its factory or mid-run, is a
:class:`~hil.plugins.PluginError` naming the scheme, the call and when; the run ends on it as an error
(exit status 2, one line), its board disarmed where the link still allows. An
:class:`InProcessBoard` (the host's own machinery: its clock, its world) is not wrapped.
"""

from __future__ import annotations

from hil.plugins import PluginError, Registry, call_plugin
from protocol.errors import HilError, TransportError, TransportRefused

from .base import Transport, UrlOptions
from .in_process import InProcessBoard, SimulatedWorld, WorldStream, WorldTruth

ENTRY_POINT_GROUP = "vscmg_hil.transports"

# scheme -> "module:factory"; the factory takes the URL and returns an unopened Transport.
_BUILT_IN = {
    "socket": "hil.link.transports.serial_port:SerialTransport",
    "loop": "hil.link.transports.serial_port:SerialTransport",
    "spy": "hil.link.transports.serial_port:SerialTransport",
    "rfc2217": "hil.link.transports.serial_port:SerialTransport",
    "hwgrep": "hil.link.transports.serial_port:SerialTransport",
    "can": "hil.link.transports.can_bus:CanTransport",
}
_REGISTRY = Registry(ENTRY_POINT_GROUP, _BUILT_IN)
# the transports not wrapped in a CheckedTransport: hil's own, and the emulator's this project registers
# (firmware_sim's entry points: the default run's hot path)
_UNCHECKED = frozenset(
    {
        *_BUILT_IN.values(),
        "firmware_sim.servers.transports:EmulatorTransport",
        "firmware_sim.servers.transports:SpawnTransport",
    }
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
    """The transport for ``url``, not yet opened. A scheme neither ``hil`` nor ``firmware_sim`` ships is
    built wrapped in a :class:`~.checked.CheckedTransport` (unless it is an :class:`InProcessBoard`); its
    factory raising anything but the project's own errors, or returning what is not a
    :class:`Transport`, is a :class:`~hil.plugins.PluginError`. An empty (or blank) ``url`` is a
    :class:`TransportRefused` at once: as a device path it was opened, failed and tried again for the
    run's outage bound, the error naming an empty port."""
    if not url.strip():
        raise TransportRefused(
            f"{url!r}: an empty port: give a device path (/dev/ttyACM0) or a transport URL "
            f"({', '.join(s + '://' for s in schemes())})"
        )
    scheme = _scheme_of(url)
    if scheme == "serial":
        from .serial_port import SerialTransport

        return SerialTransport(url)
    target = _REGISTRY.target(scheme)
    if target is None:
        raise TransportError(f"{url}: unknown transport scheme {scheme!r} (known: {_REGISTRY.known()})")
    try:
        factory = _REGISTRY.load(target)
    except (ImportError, AttributeError) as exc:
        raise TransportError(f"{url}: transport {target} is not available: {exc}") from exc
    if target in _UNCHECKED:
        transport: Transport = factory(url)
        return transport
    plugin = f"transport {scheme!r}"
    # the project's own (a TransportError naming an option) passes as raised
    built = call_plugin(plugin, f"its factory {target}", lambda: factory(url), HilError)
    if not isinstance(built, Transport):
        raise PluginError(plugin, f"its factory {target} returned {type(built).__name__}, not a Transport")
    if isinstance(built, InProcessBoard):  # the host's own machinery (its clock, its world): as it is
        return built
    from .checked import CheckedTransport

    return CheckedTransport(built, scheme)


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
