"""``hil selftest --vectors FILE`` beside a document whose sections are not arrays or whose vectors' names,
messages or reasons are not strings (a hand's edit, another program's export): ``"frames": 5``,
``"streams": null`` or a name that is a list ended the selftest in a ``TypeError`` traceback (status 1),
and a frame named by a list passed. Each is now a failed line naming the section or the vector, the rest
of the document still checked."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.vectors.check import SECTIONS, check_document

VECTORS = Path(__file__).resolve().parents[1] / "fixtures" / "protocol_vectors.json"
CANONICAL = json.loads(VECTORS.read_text())
NOT_ARRAYS = st.one_of(
    st.none(), st.integers(), st.floats(allow_nan=True), st.text(max_size=3), st.booleans(),
    st.dictionaries(st.text(max_size=2), st.integers(), max_size=2),
)  # fmt: skip
NOT_STRINGS = st.one_of(st.none(), st.integers(), st.lists(st.integers(), max_size=2), st.booleans())


def _copy() -> dict:
    return json.loads(json.dumps(CANONICAL))


@settings(max_examples=60, deadline=None)
@given(section=st.sampled_from(SECTIONS), value=NOT_ARRAYS)
def test_a_section_that_is_no_array_is_its_failed_line_and_the_rest_is_checked(section, value):
    document = _copy()
    document[section] = value
    results = check_document(document)
    failed = {r.name: r for r in results if not r.ok}
    assert section in failed and "expected an array of vectors" in failed[section].detail
    others = [key for key in SECTIONS if key != section]
    checked = {r.name for r in results}
    for key in others:  # every other section's vectors still checked, each by name
        for i, vector in enumerate(CANONICAL[key]):
            assert vector.get("name", f"{key}[{i}]") in checked


@settings(max_examples=60, deadline=None)
@given(
    where=st.sampled_from(
        [("frames", "name"), ("frames", "message"), ("bad_frames", "name"), ("bad_frames", "reason"),
         ("streams", "name")]
    ),
    value=NOT_STRINGS,
)  # fmt: skip
def test_a_vector_whose_name_message_or_reason_is_no_string_fails_and_nothing_raises(where, value):
    section, key = where
    document = _copy()
    document[section][0][key] = value
    results = check_document(document)
    failed = [r for r in results if not r.ok]
    if key == "name":  # the vector itself fails, reported under its place in the document
        assert f"{section}[0]" in {r.name for r in failed}
    assert failed  # a field a vector's check reads, or the coverage it counts towards, fails


def test_hil_selftest_on_sections_that_are_no_arrays_is_failed_lines_not_a_traceback(tmp_path):
    document = _copy()
    document["frames"], document["streams"] = 5, None
    document["bad_frames"][0]["reason"] = [1]
    path = tmp_path / "vectors.json"
    path.write_text(json.dumps(document))
    done = subprocess.run(
        [sys.executable, "-m", "hil", "selftest", "--vectors", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    out = done.stdout + done.stderr
    assert done.returncode == 1 and "Traceback" not in out, out[-2000:]
    assert "FAIL frames: expected an array of vectors, got int" in out
    assert "FAIL streams: expected an array of vectors, got NoneType" in out
