"""The install's warm-up (``python -m hil.runtime.warmup --install``, what setup.py runs) with compiling
switched off (``NUMBA_DISABLE_JIT=1``): it says that nothing was compiled, and why — not "in the cache
already", which pip showed though nothing was in any cache — and writes nothing into the cache folder:
no marker, no build. In a subprocess with its own ``NUMBA_CACHE_DIR``."""

from __future__ import annotations

import os
import subprocess
import sys

WORLD_TRANSPORT = "emu=firmware_sim.servers.transports:EmulatorTransport"  # as setup.py registers it


def test_the_installs_warm_up_with_compiling_off_says_nothing_was_compiled(tmp_path):
    cache = tmp_path / "numba-cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "NUMBA_DISABLE_JIT": "1"}
    command = [sys.executable, "-m", "hil.runtime.warmup", "--install", f"--transport={WORLD_TRANSPORT}"]
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "kernels: not compiled (compiling is switched off: NUMBA_DISABLE_JIT=1)", (
        done.stdout + done.stderr[-2000:]
    )
    assert not cache.exists() or not any(cache.iterdir())
