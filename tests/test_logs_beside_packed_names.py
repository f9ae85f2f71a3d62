"""A log compressed or archived under a name that does not say so (``log.csv`` holding gzip data, a zip
renamed ``.csv`` inside a folder, a ``bzip2`` or ``xz`` file): it was only "not a recognised log". The
error now names the file and what its bytes are, and how to have it read (a ``.gz`` or ``.zip`` is read
so named); the same bytes so named replay."""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import zipfile
from pathlib import Path

import pytest

from hil.logs import read_log
from protocol.errors import InputFormatError

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "logs" / "simulated_testbed_4s.csv"


def _zipped(data: bytes) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as z:
        z.writestr("log.csv", data)
    return buffer.getvalue()


PACKERS = {".gz": gzip.compress, ".zip": _zipped, ".bz2": bz2.compress, ".xz": lzma.compress}


@pytest.mark.parametrize("ext", sorted(PACKERS))
@pytest.mark.parametrize("in_folder", [False, True])
def test_a_packed_log_under_a_plain_name_is_said_so_and_so_named_is_read(tmp_path, ext, in_folder):
    data = PACKERS[ext](FIXTURE.read_bytes())
    folder = tmp_path / "export" if in_folder else tmp_path
    folder.mkdir(exist_ok=True)
    plain = folder / "log.csv"
    plain.write_bytes(data)
    if ext == ".zip" and not in_folder:  # a zip given by name is opened as one whatever its name
        assert read_log(plain).n_samples == read_log(FIXTURE).n_samples
        return
    with pytest.raises(InputFormatError) as caught:
        read_log(folder if in_folder else plain)
    said = str(caught.value)
    assert "not a recognised log" in said and f"log.csv is {ext} data" in said, said
    assert f"name it log.csv{ext}" in said
    if ext in (".gz", ".zip"):
        plain.rename(folder / f"log.csv{ext}")
        log = read_log(folder / f"log.csv{ext}")
        assert log.n_samples == read_log(FIXTURE).n_samples


def test_a_plain_text_that_is_no_log_gets_no_such_hint(tmp_path):
    path = tmp_path / "notes.csv"
    path.write_text("a,b\n1,2\n")
    with pytest.raises(InputFormatError) as caught:
        read_log(path)
    assert "data under a name" not in str(caught.value)
