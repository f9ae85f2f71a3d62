"""Both Python ends dispatch by message type through a table with an entry for every catalogue message: the
emulated board's ``EXECUTE`` and the host session's ``RECEIVE``. A message added to the catalogue without
its entries fails here, once per side, naming the message (docs/protocol.md, "Adding a message")."""

from __future__ import annotations

import pytest

from firmware_sim.board.commands import EXECUTE
from hil.link.board.session import RECEIVE
from protocol.messages import CATALOGUE

TABLES = {
    "firmware_sim.board.commands.EXECUTE": EXECUTE,
    "hil.link.board.session.RECEIVE": RECEIVE,
}


@pytest.mark.parametrize("table", TABLES)
@pytest.mark.parametrize("message", CATALOGUE, ids=lambda cls: cls.__name__)
def test_every_catalogue_message_has_an_entry(table, message):
    assert message in TABLES[table], (
        f"{message.__name__} ({message.MSG_ID:#04x}) is in protocol.messages.CATALOGUE but has no entry in "
        f"{table}: say what this end does with it (docs/protocol.md, 'Adding a message')"
    )


@pytest.mark.parametrize("table", TABLES)
def test_no_entry_for_a_message_outside_the_catalogue(table):
    extra = [cls.__name__ for cls in TABLES[table] if cls not in CATALOGUE]
    assert not extra, f"{table} has entries for messages not in the catalogue: {extra}"
