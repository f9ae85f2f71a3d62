"""Files joined one after another (``cat a.csv b.csv``, docs/formats.md: the header repeated is passed
over and noted) when each was saved with a byte-order mark — Excel's "CSV UTF-8", or its "Unicode text"
(UTF-16) — hold a second mark at the start of the line the second file begins on. The repeated header was
then an error, "'\\ufefftime' is not a number", and a joined file without a header (tyrex's) "'\\ufeff0.01'
is not a number": the mark is no part of any cell, wherever a line starts with it.

The files are built in tmp_path from the real recordings (the Sensor Logger export; a tyrex trial's
files gunzipped, as users keep them)."""

from __future__ import annotations

import gzip

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import (
    REAL_FILES,
    REAL_LINES,
    assert_same_samples,
    needs_real_export,
    real_export,
    real_lines,
)

from hil.logs import read_log
from hil.scenario.paths import SHARED_DATA

SETTINGS = settings(
    max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
TYREX_TRIAL = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_NoDist_Texting"
TYREX_FILES = ("accelerometer.txt", "gyroscope-calibrated.txt", "magnetometer-calibrated.txt")
TYREX_LINES = 3000  # per file: ~15 s of the trial


def _joined(parts: list[list[str]], encoding: str, newline: str) -> bytes:
    """Each part saved on its own with a byte-order mark (``utf-8-sig``, ``utf-16``), then joined."""
    return b"".join((newline.join(part) + newline).encode(encoding) for part in parts)


@pytest.fixture(scope="module")
def plain_export(tmp_path_factory):
    return read_log(real_export(tmp_path_factory.mktemp("plain") / "rec"))


@needs_real_export
@SETTINGS
@given(
    name=st.sampled_from(REAL_FILES),
    at=st.integers(2, REAL_LINES - 2),
    encoding=st.sampled_from(["utf-8-sig", "utf-16-le", "utf-16"]),
    newline=st.sampled_from(["\n", "\r\n"]),
    header_again=st.booleans(),
)
def test_a_sensor_logger_file_joined_from_files_with_byte_order_marks_reads_as_the_one_file(
    tmp_path_factory, plain_export, name, at, encoding, newline, header_again
):
    lines = real_lines(name)
    parts = [lines[:at], [*([lines[0]] if header_again else []), *lines[at:]]]
    if encoding == "utf-16-le":  # a mark written by hand before each part, little-endian
        data = b"".join(b"\xff\xfe" + (newline.join(p) + newline).encode("utf-16-le") for p in parts)
    else:
        data = _joined(parts, encoding, newline)
    folder = real_export(tmp_path_factory.mktemp("joined") / "rec")
    (folder / name).write_bytes(data)
    log = read_log(folder)
    assert_same_samples(log, plain_export)
    repeated = [note for note in log.notes if "header repeated" in note]
    assert bool(repeated) == header_again and (not repeated or f"({at + 1})" in repeated[0]), repeated


@pytest.mark.skipif(not TYREX_TRIAL.is_dir(), reason="the shared tyrex trial is not here")
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    name=st.sampled_from(TYREX_FILES),
    at=st.integers(1, TYREX_LINES - 1),
    encoding=st.sampled_from(["utf-8-sig", "utf-16"]),
)
def test_a_tyrex_file_joined_from_files_with_byte_order_marks_reads_as_the_one_file(
    tmp_path_factory, name, at, encoding
):
    """A table without a header: the second file's mark stood before its first row's time."""
    texts = {}
    for file in TYREX_FILES:
        with gzip.open(TYREX_TRIAL / f"{file}.gz", "rt") as f:
            texts[file] = [next(f).rstrip("\n") for _ in range(TYREX_LINES)]
    plain = tmp_path_factory.mktemp("plain")
    joined = tmp_path_factory.mktemp("joined")
    for file, lines in texts.items():
        (plain / file).write_text("\n".join(lines) + "\n")
        (joined / file).write_text("\n".join(lines) + "\n")
    lines = texts[name]
    (joined / name).write_bytes(_joined([lines[:at], lines[at:]], encoding, "\n"))
    log, reference = read_log(joined), read_log(plain)
    for kind, stream in reference.streams.items():
        np.testing.assert_array_equal(log.streams[kind].t, stream.t)
        np.testing.assert_array_equal(log.streams[kind].xyz, stream.xyz)
