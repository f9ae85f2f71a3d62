"""``hil gcs A B`` where one of the directories is a symlink loop (or a path through one, or a dangling
link): the one line ``hil gcs LOOP`` gives alone ("not a directory", exit 2), never a traceback.

``CompareSource`` resolved every path (for the "given twice" check) before checking it, and
``Path.resolve`` raises RuntimeError ("Symlink loop") on Python 3.11: ``hil gcs RUN LOOP`` ended in a
traceback, exit 1.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from gcs_support import quick_scenario

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from protocol.errors import InputFormatError


@pytest.fixture(scope="module")
def a_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("compare-links")
    return run(quick_scenario(), RunOptions(out_root=root, duration_s=1.0)).run_dir


def _odd_path(tmp_path, kind):
    """A link to itself, two links to each other, a path through a loop, or a link to nothing."""
    (tmp_path / "self").symlink_to("self")
    (tmp_path / "ping").symlink_to("pong")
    (tmp_path / "pong").symlink_to("ping")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    paths = {
        "self": tmp_path / "self",
        "pair": tmp_path / "ping",
        "through": tmp_path / "self" / "inside",
        "dangling": tmp_path / "dangling",
    }
    return paths[kind]


@pytest.mark.parametrize("odd_first", [False, True])
@pytest.mark.parametrize("kind", ["self", "pair", "through", "dangling"])
def test_a_symlink_loop_among_the_runs_compared_is_refused_in_one_line(a_run, tmp_path, kind, odd_first):
    odd = _odd_path(tmp_path, kind)
    dirs = [odd, a_run] if odd_first else [a_run, odd]
    with pytest.raises(InputFormatError, match="not a directory"):
        GroundStation.compare(dirs, bind="127.0.0.1:0")
    cli = subprocess.run(
        [sys.executable, "-m", "hil", "gcs", *map(str, dirs), "--gcs", "127.0.0.1:0", "--no-follow"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert cli.returncode == 2, cli.stderr
    assert cli.stderr == f"hil gcs: error: {odd}: not a directory\n"
