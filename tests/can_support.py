"""CAN buses for tests: fresh ``virtual`` channels and ``udp_multicast`` groups, and whether this machine
can carry IPv4 multicast at all (a sandbox without a multicast route cannot: its tests are then skipped
with that reason, through the ``udp_multicast`` marker in tests/conftest.py — and CI, which sets
``VSCMG_HIL_REQUIRE_ALL=1``, fails instead of skipping)."""

from __future__ import annotations

import functools
import itertools
import os
import random

_channels = itertools.count()


def virtual_url(fd: bool = False, node: int = 5) -> str:
    """A ``can://virtual/...`` URL on a channel no other test in this process uses."""
    return f"can://virtual/test-{os.getpid()}-{next(_channels)}?node={node}&fd={int(fd)}"


def multicast_url(fd: bool = False, node: int = 5) -> str:
    """A ``can://udp_multicast/...`` URL on a group and port drawn at random: another test run on the same
    machine (another checkout) is on another group, and frames of another node are ignored anyway."""
    group = f"239.74.{random.randint(0, 255)}.{random.randint(1, 254)}"
    return f"can://udp_multicast/{group}?port={random.randint(40_000, 60_000)}&node={node}&fd={int(fd)}"


@functools.cache
def udp_multicast_problem() -> str | None:
    """Why python-can's ``udp_multicast`` interface cannot carry a frame between two buses on this
    machine, or None when it can (one frame sent and received, both ways of asking the kernel tried)."""
    import can

    url = multicast_url()
    group, _, port = url.removeprefix("can://udp_multicast/").partition("?port=")
    port_number = int(port.partition("&")[0])
    try:
        with (
            can.Bus(interface="udp_multicast", channel=group, port=port_number) as a,
            can.Bus(interface="udp_multicast", channel=group, port=port_number) as b,
        ):
            a.send(can.Message(arbitration_id=0x123, data=b"probe", is_extended_id=False))
            for _ in range(20):
                msg = b.recv(0.1)
                if msg is not None and msg.arbitration_id == 0x123:
                    return None
            return f"a frame sent to the IPv4 multicast group {group} never arrived (no multicast route?)"
    except (OSError, can.CanError) as exc:
        return f"IPv4 multicast is not available here: {exc}"
