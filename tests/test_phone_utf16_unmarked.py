"""UTF-16 without a byte-order mark was recognised only when its first 8 characters were ASCII: a first
line in Cyrillic, Chinese or with a ``µ`` made the file "binary data". Now its NUL bytes tell it
(:func:`hil.logs.encoding.unmarked_utf16`), and binary bytes still do not pass for it."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import assert_same_samples, needs_real_export, real_export

from hil.logs import detect_format, read_log
from protocol.errors import InputFormatError

SETTINGS = settings(
    max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

pytestmark = needs_real_export


@pytest.fixture(scope="module")
def real_log(tmp_path_factory):
    return read_log(real_export(tmp_path_factory.mktemp("real") / "export"))


# --------------------------------------------------------------------------- 3. UTF-16 without a mark
COMMENT = st.text(
    st.characters(blacklist_categories=("Cc", "Cs", "Zl", "Zp"), blacklist_characters="\ufeff"),
    min_size=1,
    max_size=30,
)


@SETTINGS
@given(
    comment=COMMENT,
    order=st.sampled_from(["le", "be"]),
    first=st.sampled_from(["µT", "Время", "时间", "°", "Zeit ä"]),
)
def test_utf16_without_a_byte_order_mark_reads_whatever_script_its_first_line_is_in(
    tmp_path_factory, real_log, comment, order, first
):
    """UTF-16 without a mark was recognised only when its first 8 characters were ASCII: a comment line
    before the header in Cyrillic, Chinese or with a ``µ`` made the file 'binary data (a NUL byte)'."""

    def edit(name: str, lines: list[str]) -> list[str]:
        return [f"# {first} {comment}", *lines]

    encode = lambda name, text: text.encode(f"utf-16-{order}")  # noqa: E731
    folder = real_export(tmp_path_factory.mktemp("u16") / "rec", edit, encode)
    assert detect_format(folder) == "sensorlogger"
    assert_same_samples(read_log(folder), real_log)


@pytest.mark.parametrize(
    "head",
    [
        b"\x00" * 64,
        bytes(range(256)) * 2,
        b"PK\x03\x04" + b"\x00" * 60,
        b"\xd0\xcf\x11\xe0" + b"\x00\x01" * 40,
    ],
    ids=["nuls", "every-byte", "zip-like", "xls-like"],
)
def test_binary_bytes_are_still_no_utf16_text(tmp_path, head):
    """The wider rule takes no binary file for UTF-16: it stays an error naming the file."""
    folder = real_export(tmp_path / "rec")
    (folder / "Gyroscope.csv").write_bytes(head)
    with pytest.raises(InputFormatError) as err:
        read_log(folder)
    assert "Gyroscope.csv" in str(err.value)
