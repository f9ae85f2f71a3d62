"""hil.threads.ThreadError: a background thread's error, raised by its owner (both variants)."""

from __future__ import annotations

import logging
import threading

import pytest

from hil.threads import ThreadError
from protocol.errors import HandshakeError, HilError, LinkError


def _run_in_thread(thread_error: ThreadError, body: object) -> None:
    def target() -> None:
        with thread_error.caught(logging.getLogger("test_threads"), "the test thread failed"):
            assert callable(body)
            body()

    thread = threading.Thread(target=target)
    thread.start()
    thread.join(5.0)


def _fail() -> None:
    raise OSError(28, "No space left on device")


def test_nothing_stored_nothing_raised():
    thread_error = ThreadError("the test thread failed")
    _run_in_thread(thread_error, lambda: None)
    assert thread_error.error is None
    thread_error.check()


def test_broken_for_good_raises_a_link_error_naming_what_failed_on_every_call(caplog):
    thread_error = ThreadError("the test thread failed")
    with caplog.at_level(logging.ERROR, logger="test_threads"):
        _run_in_thread(thread_error, _fail)
    assert isinstance(thread_error.error, OSError)
    assert "the test thread failed" in caplog.text  # logged with its traceback where it happened
    for _ in range(2):
        with pytest.raises(LinkError, match=r"the test thread failed: OSError\(28") as info:
            thread_error.check()
        assert info.value.__cause__ is thread_error.error


def test_a_name_known_later_is_asked_for_when_raised():
    owner = {"url": "udp://0.0.0.0:0"}
    thread_error = ThreadError(lambda: f"phone receiver on {owner['url']} failed")
    owner["url"] = "udp://127.0.0.1:5555"  # bound after the error holder was made
    thread_error.store(ValueError("bad socket"))
    with pytest.raises(LinkError, match="udp://127.0.0.1:5555"):
        thread_error.check()


def test_as_is_types_are_raised_unchanged():
    thread_error = ThreadError("the reader thread failed", as_is=HilError)
    handshake = HandshakeError("incompatible board")
    thread_error.store(handshake)
    with pytest.raises(HandshakeError) as info:
        thread_error.check()
    assert info.value is handshake
    thread_error.store(RuntimeError("a bug"))
    with pytest.raises(LinkError, match="the reader thread failed: RuntimeError"):
        thread_error.check()


def test_clear_forgets_the_error():
    thread_error = ThreadError("the reader thread failed")
    thread_error.store(RuntimeError("raised to the caller already"))
    thread_error.clear()
    thread_error.check()


def test_raised_once_is_raised_as_it_is_then_forgotten():
    thread_error = ThreadError(None, once=True)
    _run_in_thread(thread_error, _fail)
    with pytest.raises(OSError, match="No space left"):
        thread_error.check()
    assert thread_error.error is None
    thread_error.check()  # raised once only


def test_even_a_system_exit_in_the_thread_is_kept():
    thread_error = ThreadError("the test thread failed")

    def leave() -> None:
        raise SystemExit(3)

    _run_in_thread(thread_error, leave)
    with pytest.raises(LinkError, match="SystemExit"):
        thread_error.check()
