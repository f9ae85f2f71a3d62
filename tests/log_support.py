"""What the phone-log tests share: two logs compared sample for sample."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def assert_same_samples(log, reference, kinds: Iterable | None = None) -> None:
    """``log`` holds exactly ``reference``'s samples, bit for bit: times and readings of every stream (its
    streams the same), or of ``kinds`` only."""
    if kinds is None:
        assert set(log.streams) == set(reference.streams)
        kinds = reference.streams
    for kind in kinds:
        np.testing.assert_array_equal(log.streams[kind].t, reference.streams[kind].t)
        np.testing.assert_array_equal(log.streams[kind].xyz, reference.streams[kind].xyz)
