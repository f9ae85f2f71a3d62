"""A log compressed with xz or bzip2 under the name that says so (``Gyroscope.csv.xz``, ``log.csv.bz2``,
``gyroscope-calibrated.txt.xz``: ``xz -k`` of each file) is not read compressed — only a ``.gz`` is — and
``hil replay`` refused it telling the user to "name it Gyroscope.csv.xz.xz" (the advice meant for xz data
under a name that does not say so). It now says to decompress it first; xz data under a plain name keeps
its advice to name it ``….xz``.

The files are built in tmp_path from the real Sensor Logger export."""

from __future__ import annotations

import bz2
import lzma

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import REAL_FILES, needs_real_export, real_export

from hil.cli import main

COMPRESS = {".xz": lzma.compress, ".bz2": bz2.compress}

pytestmark = needs_real_export


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(suffix=st.sampled_from(sorted(COMPRESS)), every_file=st.booleans(), named=st.booleans())
def test_an_export_compressed_with_xz_or_bzip2_is_refused_with_advice_that_fits_its_name(
    tmp_path_factory, capsys, suffix, every_file, named
):
    """``named``: the compressed file carries its suffix (``Gyroscope.csv.xz``), else it kept the plain
    name (``Gyroscope.csv`` holding xz data)."""
    folder = real_export(tmp_path_factory.mktemp("packed") / "rec")
    for name in REAL_FILES if every_file else REAL_FILES[:1]:
        data = COMPRESS[suffix]((folder / name).read_bytes())
        (folder / name).unlink()
        (folder / (name + suffix if named else name)).write_bytes(data)
    if not every_file:
        for name in REAL_FILES[1:]:  # the others gone too: nothing readable is left to choose
            (folder / name).unlink()
    status = main(["replay", str(folder), "--out", str(tmp_path_factory.mktemp("out")), "--no-plots"])
    err = capsys.readouterr().err
    assert status == 2, err
    assert suffix + suffix not in err and "decompress it first" in err, err
    if named:
        assert "does not say so" not in err, err
    else:
        assert any(f"name it {name}{suffix} (decompress it first)" in err for name in REAL_FILES), err
