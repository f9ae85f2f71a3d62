"""What the phone-log tests share: two logs compared sample for sample, and the real Sensor Logger export
of ``../shared/data`` cut short and rewritten into a test's folder (read, never copied into the project)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import pytest

from hil.scenario.paths import SHARED_DATA

REAL_SENSORLOGGER = SHARED_DATA / "sensorlogger-android"
REAL_FILES = ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv")
REAL_LINES = 400  # per file: the header and ~8 s of the recording
REAL_T0_NS = 1679068247609296600  # about the real export's first 'time' (the recording's start)
needs_real_export = pytest.mark.skipif(
    not REAL_SENSORLOGGER.is_dir(), reason="the shared Sensor Logger export is not here"
)


def real_lines(name: str, lines: int = REAL_LINES) -> list[str]:
    """The first ``lines`` lines of the real export's file ``name``, without their line ends."""
    with open(REAL_SENSORLOGGER / name, encoding="utf-8") as f:
        return [next(f).rstrip("\n") for _ in range(lines)]


def real_export(
    folder: Path,
    edit: Callable[[str, list[str]], list[str]] = lambda name, lines: lines,
    encode: Callable[[str, str], bytes] = lambda name, text: text.encode(),
) -> Path:
    """``folder`` holding the real export's three files cut to :data:`REAL_LINES`, each file's lines passed
    through ``edit(name, lines)`` and its text through ``encode(name, text)``."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in REAL_FILES:
        (folder / name).write_bytes(encode(name, "\n".join(edit(name, real_lines(name))) + "\n"))
    return folder


def assert_same_samples(log, reference, kinds: Iterable | None = None) -> None:
    """``log`` holds exactly ``reference``'s samples, bit for bit: times and readings of every stream (its
    streams the same), or of ``kinds`` only."""
    if kinds is None:
        assert set(log.streams) == set(reference.streams)
        kinds = reference.streams
    for kind in kinds:
        np.testing.assert_array_equal(log.streams[kind].t, reference.streams[kind].t)
        np.testing.assert_array_equal(log.streams[kind].xyz, reference.streams[kind].xyz)
