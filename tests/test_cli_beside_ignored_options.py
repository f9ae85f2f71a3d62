"""``hil run`` options that were taken and then ignored: ``--phone URL`` and ``--phone-wait S`` without
``--port`` ran the built-in emulator's simulated phone, the live phone asked for silently not listened to
(status 0, "completed"). Now each is refused, naming the option and how to have a live phone beside the
built-in emulator, before anything runs. And an address urllib itself refuses (``http://127.0.0.1:[/``)
was a ValueError's traceback: now a ConfigError naming ``--phone``."""

from __future__ import annotations

import pytest

from hil.cli import main
from hil.link.sources import create_source
from protocol.errors import ConfigError


@pytest.mark.parametrize(
    "given", [["--phone", "udp://0.0.0.0:8123"], ["--phone", "http://127.0.0.1:8123/"], ["--phone-wait", "3"]]
)
def test_a_live_phone_option_without_a_port_is_refused_not_ignored(tmp_path, capsys, given):
    status = main(["run", *given, "--duration", "1", "--no-plots", "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert status == 2 and f"{given[0]}: with --port only" in err and "--port emu://" in err, err
    assert not (tmp_path / "runs").exists()  # nothing ran


@pytest.mark.parametrize("address", ["http://127.0.0.1:[/", "udp://[::1", "http://[zz]:80/"])
def test_an_address_urllib_refuses_is_a_config_error_naming_the_option(address):
    with pytest.raises(ConfigError) as caught:
        create_source(address, None)  # type: ignore[arg-type]  # refused before the context is used
    assert caught.value.where == "--phone"
