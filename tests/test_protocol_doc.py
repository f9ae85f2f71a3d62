"""docs/protocol.md does not drift from the code: the generated tables are current, and — read back
independently of the generator — every message appears with its id and payload size range, every
field in its table, and the prose tables (deframer reasons, CAN ids, AOA values) match the code."""

from __future__ import annotations

import re

import pytest

from hil.scenario.paths import ROOT
from protocol import aoa, can
from protocol.__main__ import BEGIN, END, main, render_tables, replace_generated
from protocol.errors import InputFormatError
from protocol.fields import layout_of
from protocol.frame import BadFrameReason
from protocol.messages import CATALOGUE, PROTOCOL_VERSION, SCHEMA_HASH, NackReason
from protocol.vectors import payload_size_range

DOC = ROOT / "docs" / "protocol.md"
TEXT = DOC.read_text(encoding="utf-8")


def _section(title: str) -> str:
    """The text under a ``## title`` heading, up to the next ``## ``."""
    start = TEXT.index(f"\n## {title}\n")
    end = TEXT.find("\n## ", start + 1)
    return TEXT[start : end if end > 0 else len(TEXT)]


def _rows(text: str) -> list[list[str]]:
    return [
        [c.strip() for c in line.strip().strip("|").split("|")]
        for line in text.splitlines()
        if line.startswith("|")
    ]


def test_generated_tables_are_current():
    assert replace_generated(TEXT) == TEXT, "run: python -m protocol doc --write"
    assert main(["doc", "--check"]) == 0
    assert TEXT.count(BEGIN) == TEXT.count(END) == 1


def test_summary_lists_every_message_with_id_and_payload_range():
    rows = {
        r[1]: r for r in _rows(_section("Messages (byte tables)")) if re.fullmatch(r"0x[0-9a-f]{2}", r[0])
    }
    assert set(rows) == {cls.__name__ for cls in CATALOGUE}
    for cls in CATALOGUE:
        row = rows[cls.__name__]
        lo, hi = payload_size_range(cls)
        assert int(row[0], 16) == cls.MSG_ID
        assert row[2] == ("yes" if cls.RELIABLE else "no")
        assert row[3] == (str(lo) if lo == hi else f"{lo}..{hi}")


@pytest.mark.parametrize("cls", CATALOGUE, ids=lambda c: c.__name__)
def test_every_field_is_in_its_message_table_in_wire_order(cls):
    heading = f"### 0x{cls.MSG_ID:02x} {cls.__name__} "
    start = TEXT.index(heading)
    table = TEXT[start : TEXT.index("\n### ", start + 1)]
    names = [r[2].strip("`") for r in _rows(table)[2:]]
    assert names == [name for name, _ in layout_of(cls).fields]


def test_versions_hash_and_reasons_are_stated():
    assert f"`0x{SCHEMA_HASH:08x}`" in TEXT
    assert f"currently **{PROTOCOL_VERSION}**" in TEXT
    reasons = {r[-1].strip("`") for r in _rows(_section("Receiving: the deframer"))}
    assert reasons >= {r.value for r in BadFrameReason}
    for reason in NackReason:
        assert f"`{reason.name}`" in TEXT


def test_can_and_aoa_tables_match_the_code():
    can_text = _section("CAN mapping")
    by_id = {cls.MSG_ID: cls.__name__ for cls in CATALOGUE}
    for priority in can.Priority:
        match = re.search(rf"{int(priority)} {priority.name} \(([^)]*)\)", can_text)
        assert match, priority
        listed = set(re.findall(r"`(\w+)`", match.group(1)))
        assert listed == {by_id[i] for i, p in can.PRIORITY.items() if p is priority}
    aoa_rows = _rows(_section("Android Open Accessory (AOA)"))
    requests = {r[0]: r for r in aoa_rows if r[0] in {"GET_PROTOCOL", "START"}}
    assert requests["GET_PROTOCOL"][1].startswith(f"0x{aoa.REQUEST_TYPE_VENDOR_IN:02X}")
    assert int(requests["GET_PROTOCOL"][2]) == aoa.Request.GET_PROTOCOL
    assert int(requests["START"][2]) == aoa.Request.START
    strings = [r for r in aoa_rows if r[0] == "SEND_STRING"]
    assert [int(r[4].split()[0]) for r in strings] == [int(i) for i in aoa.StringIndex]
    pids = [int(r[0], 16) for r in aoa_rows if r[0].startswith("0x2D")]
    assert pids == [int(p) for p in aoa.AccessoryPid]


def test_replacing_needs_the_markers():
    with pytest.raises(InputFormatError, match="markers"):
        replace_generated("# no markers here\n")
    assert render_tables() in replace_generated(f"intro\n{BEGIN}\nold\n{END}\nrest\n")
