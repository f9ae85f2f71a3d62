"""CAN buses for the benchmarks, the soak and the tests: a fresh ``udp_multicast`` group to run on, and
whether this machine can carry IPv4 multicast at all (a sandbox without a multicast route cannot)."""

from __future__ import annotations

import functools
import random


def multicast_url(fd: bool = False, node: int | None = None) -> str:
    """A ``can://udp_multicast/…`` URL on a group and port drawn at random: another run on the same
    machine (another checkout, another benchmark) is on another bus, and frames of another node are
    ignored anyway. ``node`` None: the transport's default (0)."""
    group = f"239.74.{random.randint(0, 255)}.{random.randint(1, 254)}"
    where = f"can://udp_multicast/{group}?port={random.randint(40_000, 60_000)}"
    return f"{where}&fd={int(fd)}" + ("" if node is None else f"&node={node}")


@functools.cache
def udp_multicast_problem() -> str | None:
    """Why python-can's ``udp_multicast`` interface cannot carry a frame between two buses on this
    machine, or None when it can (one frame sent and received)."""
    import can

    url = multicast_url()
    group, _, rest = url.removeprefix("can://udp_multicast/").partition("?port=")
    port = int(rest.partition("&")[0])
    try:
        with (
            can.Bus(interface="udp_multicast", channel=group, port=port) as a,
            can.Bus(interface="udp_multicast", channel=group, port=port) as b,
        ):
            a.send(can.Message(arbitration_id=0x123, data=b"probe", is_extended_id=False))
            for _ in range(20):
                msg = b.recv(0.1)
                if msg is not None and msg.arbitration_id == 0x123:
                    return None
    except (OSError, can.CanError) as exc:
        return f"IPv4 multicast is not available here: {exc}"
    return f"a frame sent to the IPv4 multicast group {group} never arrived (no multicast route?)"
