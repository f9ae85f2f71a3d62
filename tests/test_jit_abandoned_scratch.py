"""A build killed part-way (SIGKILL, a power cut) leaves its scratch directory beside the builds: its
clean-up never ran. The next build removes such directories once they are old (an hour untouched:
:data:`hil.jit.ahead.ABANDONED_AFTER_S`) and leaves a fresh one, another process's build under way. An
install interrupted again and again filled the cache with them. One kernel built into a temporary
``NUMBA_CACHE_DIR``, in a subprocess."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from hil import jit
from hil.jit import ahead

pytestmark = [
    pytest.mark.skipif(not jit.COMPILED, reason="compiling is switched off (NUMBA_DISABLE_JIT=1)"),
    pytest.mark.skipif(not ahead.can_build(), reason="no C compiler or Python headers to build with"),
]

BUILD = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from hil.control import steering
    from hil.jit import ahead
    from hil.scenario import load_scenario

    scenario = load_scenario()
    geom = steering.VscmgSteering(scenario.spacecraft, scenario.loop.steering)._geom
    gam, w = np.array([[0.1, 0.2, 0.3, 0.4]]), np.array([[500.0, 510.0, 490.0, 505.0]])
    steering.momentum_rows(geom, gam, w, np.zeros((1, 3)))
    if len(sys.argv) > 1:  # killed in the middle of its build: the compiler's scratch left behind
        import numba.pycc
        numba.pycc.CC.compile = lambda self: (print("compiling", flush=True), time.sleep(600))
    print(ahead.build(None, [steering.momentum_rows]))
    """
)


def _build(cache: Path, *extra: str) -> subprocess.Popen[str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    env.pop(ahead.SWITCH, None)
    return subprocess.Popen(
        [sys.executable, "-c", BUILD, *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def test_a_build_killed_part_way_leaves_scratch_the_next_build_removes_once_old(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    killed = _build(cache, "killed")
    assert killed.stdout is not None
    assert killed.stdout.readline().strip() == "compiling", killed.communicate()
    killed.send_signal(signal.SIGKILL)
    killed.communicate(timeout=60)
    (left,) = list(cache.glob(f"{ahead.SCRATCH_PREFIX}*"))  # the killed build's, its clean-up never ran
    old = time.time() - ahead.ABANDONED_AFTER_S - 60
    os.utime(left, (old, old))
    under_way = cache / f"{ahead.SCRATCH_PREFIX}another"  # another process's build, begun just now
    under_way.mkdir()
    out, err = _build(cache).communicate(timeout=600)
    assert out.strip().endswith(".so"), err[-3000:]
    assert not left.exists(), "an abandoned scratch directory was left"
    assert under_way.exists(), "a build under way had its scratch directory removed"
    assert [p.name for p in cache.glob(f"{ahead.SCRATCH_PREFIX}*")] == [under_way.name]
