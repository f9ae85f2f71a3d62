"""Phone logs bounded by what their files are, not by what they claim: a zip bomb, a CSV that is one 300 MB
line, a MATLAB file whose compressed element inflates to a gigabyte, an archive of a hundred thousand
entries, and random hostile files (random bytes, one long line, NUL bytes, nesting, compressed) into every
reader — each refused with one InputFormatError naming the file (and the line), in bounded time and
memory. ``hil replay`` is measured from outside, as a process: its peak resident memory and its time.

The big inputs are generated into ``tmp_path`` a piece at a time (never held in the test's memory)."""

from __future__ import annotations

import gzip
import struct
import time
import tracemalloc
import zipfile
import zlib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from measure_support import MB, run_measured

from hil.logs import READERS, read_log
from hil.logs import table as log_table
from hil.logs.replay import ReplayOptions, replay
from hil.scenario.paths import FIXTURES
from protocol.errors import InputFormatError

REPLAY_PEAK_LIMIT = 512 * MB
SENSOR_LOGGER_HEADER = "time,seconds_elapsed,z,y,x\n"


def zip_bomb(path: Path, nul_bytes: int) -> Path:
    """A Sensor Logger export whose Gyroscope.csv is a header then ``nul_bytes`` NUL bytes (deflated about
    1000:1), written to the archive a megabyte at a time."""
    rows = "".join(
        f"{1_669_000_000_000_000_000 + i * 10_000_000},{i * 0.01:.2f},9.8,0.1,0.2\n" for i in range(100)
    )
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        archive.writestr("TotalAcceleration.csv", SENSOR_LOGGER_HEADER + rows)
        with archive.open("Gyroscope.csv", "w", force_zip64=True) as member:
            member.write(SENSOR_LOGGER_HEADER.encode())
            block = bytes(MB)
            for _ in range(nul_bytes // MB):
                member.write(block)
    return path


def test_a_zip_bomb_is_refused_after_its_first_megabytes_in_bounded_memory_and_time(tmp_path):
    bomb = zip_bomb(tmp_path / "export.zip", 1 << 30)  # 1 GiB of NUL bytes in a 1 MB zip
    assert bomb.stat().st_size < 2 * MB
    status, peak, seconds, stderr = run_measured("replay", str(bomb), "--out", str(tmp_path / "out"))
    assert status == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "export.zip:Gyroscope.csv:2:" in lines[0], stderr
    assert peak < REPLAY_PEAK_LIMIT, f"peak {peak / MB:.0f} MB"
    assert seconds < 60, f"{seconds:.0f} s"


def test_a_300_mb_csv_of_one_line_after_its_header_is_refused_in_bounded_memory(tmp_path):
    path = tmp_path / "long.csv"
    row = b"0.000000,gyr,0.1,0.2,0.3,"  # no line break, ever
    with path.open("wb") as f:
        f.write(b"# vscmg-hil sensor log v1\nt_s,sensor,x,y,z,w\n")
        block = row * (MB // len(row))
        for _ in range(300):
            f.write(block)
    status, peak, seconds, stderr = run_measured("replay", str(path), "--out", str(tmp_path / "out"))
    assert status == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "long.csv:3:" in lines[0] and "line longer than" in lines[0], stderr
    assert peak < REPLAY_PEAK_LIMIT, f"peak {peak / MB:.0f} MB"
    assert seconds < 60, f"{seconds:.0f} s"


def test_a_gzip_member_that_expands_past_the_ratio_is_refused_naming_it(tmp_path):
    """A tyrex trial whose accelerometer.txt.gz is a header row then 200 MB of one repeated comment line
    (short lines, no samples, under the member cap): its compression ratio gives it away."""
    trial = tmp_path / "trial"
    trial.mkdir()
    with gzip.open(trial / "accelerometer.txt.gz", "wb", compresslevel=9) as f:
        f.write(b"0.0 0.1 0.2 9.8\n")
        block = (b"#" + b" " * 1022 + b"\n") * 1024
        for _ in range(200):
            f.write(block)
    tracemalloc.start()
    try:
        with pytest.raises(InputFormatError, match="compression bomb") as info:
            read_log(trial)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert info.value.path.endswith("accelerometer.txt.gz")
    assert peak < 32 * MB, f"{peak / MB:.0f} MB traced"


def mat_with_compressed_element(path: Path, inflated: int) -> Path:
    """A level-5 MAT file holding one miCOMPRESSED element whose zlib stream inflates to ``inflated`` bytes
    (a header claiming an array, then zeros), compressed a megabyte at a time."""
    packer = zlib.compressobj(9)
    body = [packer.compress(struct.pack("<II", 14, inflated - 8))]
    block = bytes(MB)
    for _ in range(inflated // MB):
        body.append(packer.compress(block))
    body.append(packer.flush())
    packed = b"".join(body)
    header = b"MATLAB 5.0 MAT-file".ljust(116, b" ") + bytes(8) + struct.pack("<H", 0x0100) + b"IM"
    path.write_bytes(header + struct.pack("<II", 15, len(packed)) + packed)
    return path


def test_a_mat_file_whose_compressed_element_inflates_to_a_gigabyte_is_refused(tmp_path):
    mat = mat_with_compressed_element(tmp_path / "trial.mat", 1 << 30)
    assert mat.stat().st_size < 2 * MB
    start = time.monotonic()
    tracemalloc.start()
    try:
        with pytest.raises(InputFormatError, match="inflate|compression bomb") as info:
            READERS["broad"].read(log_table.Container(mat))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert info.value.path.endswith("trial.mat")
    assert peak < 32 * MB and time.monotonic() - start < 30


def test_a_zip_of_a_hundred_thousand_entries_is_refused_before_its_directory_is_read(tmp_path):
    path = tmp_path / "many.zip"
    with zipfile.ZipFile(path, "w") as archive:
        for i in range(100_000):
            archive.writestr(f"f{i}.csv", b"")
    with pytest.raises(InputFormatError, match="100000 entries") as info:
        read_log(path)
    assert info.value.path == str(path)


def test_a_log_longer_than_the_sample_cap_is_refused_naming_the_line_it_reached(tmp_path, monkeypatch):
    monkeypatch.setattr(log_table, "MAX_LOG_SAMPLES", 500)
    path = tmp_path / "log.csv"
    rows = "".join(f"{i * 0.01:.2f},gyr,0.1,0.2,0.3,\n" for i in range(1000))
    path.write_text("t_s,sensor,x,y,z,w\n" + rows)
    with pytest.raises(InputFormatError, match="more than 500 samples") as info:
        read_log(path)
    assert info.value.line == 1001  # the batch it had reached: the whole small file


def test_a_replay_longer_than_the_step_cap_is_refused_before_merging_and_a_window_of_it_runs(
    tmp_path, monkeypatch
):
    from hil.logs import replay as replay_module

    monkeypatch.setattr(replay_module, "MAX_REPLAY_STEPS", 300)
    log = FIXTURES / "logs" / "simulated_testbed_4s.csv"
    with pytest.raises(InputFormatError, match="more than 300 at once.*--window") as info:
        replay(log, ReplayOptions(out_dir=tmp_path / "all"))
    assert info.value.path == str(log)
    result = replay(log, ReplayOptions(out_dir=tmp_path / "part", window_s=(0.0, 0.5)))
    assert 0 < len(result.estimates) <= 300


# --------------------------------------------------------------------------- the line splitter
@given(
    pieces=st.lists(st.binary(max_size=40), max_size=30),
    max_line=st.integers(1, 20),
)
def test_the_line_splitter_gives_every_line_once_in_order_whatever_the_pieces(pieces, max_line):
    """Against a trivial model (split the whole text at once): same lines, each over-long one as None."""
    from hil.files.bounded import LineSplitter

    data = b"".join(pieces)
    splitter = LineSplitter(max_line)
    got: list[bytes | None] = []
    for piece in pieces:
        got += splitter.feed(piece)
        assert splitter.pending <= max_line
    got += splitter.end()
    text = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    expected: list[bytes | None] = [line if len(line) <= max_line else None for line in text.split(b"\n")]
    if expected and expected[-1] == b"":
        expected.pop()  # a final line break ends the last line; it starts none
    assert got == expected


# --------------------------------------------------------------------------- random hostile files
MEMBERS = {
    "csv": "log.csv",
    "sensorlogger": "Gyroscope.csv",
    "phyphox": "Accelerometer.csv",
    "tyrex": "accelerometer.txt",
    "broad": "trial.mat",
}
HEADS = {
    "csv": b"t_s,sensor,x,y,z,w\n",
    "sensorlogger": SENSOR_LOGGER_HEADER.encode(),
    "phyphox": b'"Time (s)","X (m/s^2)","Y (m/s^2)","Z (m/s^2)"\n',
    "tyrex": b"",
    "broad": b"MATLAB 5.0 MAT-file".ljust(116, b" ") + bytes(8) + b"\x00\x01IM",
}


def _body(shape: str, size: int, noise: bytes) -> bytes:
    """What follows a plausible header: ``size`` bytes of one hostile shape."""
    if shape == "random":
        return (noise * (size // max(len(noise), 1) + 1))[:size] if noise else bytes(size)
    if shape == "one line":
        return b"1.0," * (size // 4)
    if shape == "nul":
        return bytes(size)
    if shape == "nested":
        return b"[" * size
    return b"0,0,0,0,0,0\n" * (size // 12)  # "many rows": plausible, repetitive


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    format=st.sampled_from(sorted(MEMBERS)),
    shape=st.sampled_from(["random", "one line", "nul", "nested", "many rows"]),
    size=st.sampled_from([0, 1000, MB + 1000, 3 * MB]),  # MB + 1000: past the line cap
    noise=st.binary(min_size=0, max_size=64),
    wrapping=st.sampled_from(["plain", "zip", "gz", "zip of gz"]),
    detect=st.booleans(),
)
def test_random_hostile_files_into_every_reader_end_in_a_log_or_one_typed_error(
    tmp_path_factory, format, shape, size, noise, wrapping, detect
):
    """Every reader, given a plausible header then bytes of a hostile shape (plain, zipped, gzipped, both),
    returns a log or raises InputFormatError naming the file, within seconds and a bounded memory."""
    folder = tmp_path_factory.mktemp("hostile")
    member = MEMBERS[format]
    data = HEADS[format] + _body(shape, size, noise)
    if wrapping in ("gz", "zip of gz"):
        member += ".gz"
        data = gzip.compress(data, compresslevel=1)
    if wrapping in ("zip", "zip of gz"):
        path = folder / "export.zip"
        with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
            archive.writestr(member, data)
    else:
        path = folder / member
        path.write_bytes(data)
        if format != "csv" and format != "broad":
            path = folder  # the formats that are folders of files
    start = time.monotonic()
    tracemalloc.start()
    try:
        try:
            read_log(path, None if detect else format)
        except InputFormatError as exc:
            assert exc.path, exc  # names a file
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 96 * MB, f"{peak / MB:.0f} MB traced"
    assert time.monotonic() - start < 20


def test_every_bound_is_reported_as_the_project_error_not_a_traceback(tmp_path):
    """The readers' own edge: a zip member that is not what its directory says (a damaged deflate
    stream) is one InputFormatError naming the member."""
    path = tmp_path / "export.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("Gyroscope.csv", SENSOR_LOGGER_HEADER + "1,0,0,0,0\n" * 10_000)
    raw = bytearray(path.read_bytes())
    start = raw.index(b"Gyroscope.csv") + len("Gyroscope.csv") + 40
    raw[start : start + 64] = bytes(64)  # damage the deflate stream, not the directory
    path.write_bytes(bytes(raw))
    with pytest.raises(InputFormatError) as info:
        read_log(path, "sensorlogger")
    assert "Gyroscope.csv" in info.value.path
