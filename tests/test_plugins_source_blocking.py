"""A user's phone source whose mid-run call never returns — a ``drain`` blocked on a socket read with no
timeout, a ``truth`` waiting on a lock — ends ``hil run`` as an error naming the source, the call and its
time, the board disarmed and the summary written (:data:`hil.link.sources.checked.LIVE_CALL_WAIT_S`,
shortened here); one that is slow but returns within the bound is waited for. In real ``hil`` processes:
a thread blocked for good cannot be stopped, and is left in the process that ran it.

Before: such a source hung ``hil run`` until it was killed, as an estimator's blocked step did."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent

SOURCE = '''
import threading
import time

from plugin_support import still_samples
from hil.link.sources import PhoneSource


class Stuck(PhoneSource):
    """A phone lying still, whose call named by its URL's host blocks (or sleeps 1.5 s) at its n-th use."""

    def __init__(self, url, context):
        self.url, self.next_t, self.calls = url, None, {}
        how, _, rest = url.split("://", 1)[1].partition("-")
        self.call, self.how, self.at = how, *rest.split("-")
        self.at = int(self.at)

    def _maybe_block(self, call):
        self.calls[call] = self.calls.get(call, 0) + 1
        if call == self.call and self.calls[call] == self.at:
            if self.how == "block":
                threading.Event().wait()
            else:
                time.sleep(1.5)

    def drain(self, now):
        self._maybe_block("drain")
        out, self.next_t = still_samples(now if self.next_t is None else self.next_t, now)
        return out

    def truth(self, now):
        self._maybe_block("truth")
        return None

    def close(self):
        """Nothing to release."""
'''


def _hil(root: Path, url: str, bound_s: float) -> subprocess.CompletedProcess[str]:
    (root / "stuck_source_for_test.py").write_text(SOURCE)
    script = textwrap.dedent(
        f"""
        import sys
        sys.path[:0] = [{str(root)!r}, {str(TESTS)!r}, {str(REPO)!r}]
        import hil.link.sources.checked as checked
        checked.LIVE_CALL_WAIT_S = {bound_s!r}
        from hil.link import sources
        sources.register("stuck", "stuck_source_for_test:Stuck")
        from hil.cli import main
        args = ["run", "--port", "emu://", "--phone", {url!r}, "--duration", "6", "--no-plots"]
        sys.exit(main([*args, "--out", "runs"]))
        """
    )
    return subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=240, cwd=root
    )


def _summary(root: Path) -> dict:
    (run_dir,) = (root / "runs").iterdir()
    return json.loads((run_dir / "summary.json").read_text())


@pytest.mark.parametrize(
    ("url", "said"),
    [
        ("stuck://drain-block-300", "drain at t = "),  # in the warm-up
        ("stuck://drain-block-1200", "drain at t = "),  # slewing
        ("stuck://truth-block-200", "truth at t = "),
    ],
)
def test_a_source_call_that_never_returns_ends_the_run_as_an_error_with_the_board_disarmed(
    tmp_path, url, said
):
    run = _hil(tmp_path, url, 1.0)
    assert (tmp_path / "runs").is_dir(), run.stderr[-3000:]
    summary = _summary(tmp_path)
    assert run.returncode == 2, (run.returncode, summary["exit"], run.stderr[-2000:])
    assert summary["exit"].startswith(f"error: phone source 'stuck': {said}"), summary["exit"]
    assert "did not return within 1 s" in summary["exit"], summary["exit"]
    assert summary["final_disarm"]["state"] == "DISARMED" and summary["final_disarm"]["ok"], summary
    assert "Traceback" not in run.stderr, run.stderr


def test_a_source_call_slow_but_within_its_bound_is_waited_for(tmp_path):
    run = _hil(tmp_path, "stuck://drain-sleep-1200", 3.0)
    assert run.returncode in (0, 1), run.stderr[-2000:]
    assert "did not return" not in _summary(tmp_path)["exit"]
