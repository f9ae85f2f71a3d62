"""A fresh install's first run compiles its kernels on both cores at once (hil.runtime.warmup), and the
run after it finds every kernel it calls in numba's cache: it compiles none."""

import os
import subprocess
import sys
import textwrap

import pytest

from hil import jit

pytestmark = pytest.mark.skipif(not jit.COMPILED, reason="compiling is switched off (NUMBA_DISABLE_JIT=1)")

COUNT_MISSES = textwrap.dedent('''
    import importlib, json, pkgutil, sys
    import numba
    from hil.runtime import RunOptions, run
    from hil.runtime.warmup import marker, needed
    from hil.scenario import load_scenario

    before = needed()
    run(load_scenario(), RunOptions(out_root=None, duration_s=1.0))
    misses = []
    for pkg in ("hil.vscmg", "hil.estimation", "hil.control", "hil.so3", "firmware_sim.world.models"):
        for info in pkgutil.walk_packages(importlib.import_module(pkg).__path__, pkg + "."):
            module = importlib.import_module(info.name)
            for name, obj in vars(module).items():
                if isinstance(obj, numba.core.registry.CPUDispatcher) and obj.stats.cache_misses:
                    misses.append(f"{info.name}.{name}")
    print(json.dumps({"needed_before": before, "marker": marker().exists(), "misses": sorted(set(misses))}))
''')  # fmt: skip


def _run(code: str, cache: str) -> str:
    env = {**os.environ, "NUMBA_CACHE_DIR": cache}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


def test_a_fresh_cache_is_compiled_once_and_the_next_run_compiles_nothing(tmp_path):
    import json

    cache = str(tmp_path / "numba-cache")
    first = json.loads(_run(COUNT_MISSES, cache))  # a fresh install: warm-up, then the run
    assert first["needed_before"] and first["marker"]
    second = json.loads(_run(COUNT_MISSES, cache))
    assert not second["needed_before"] and second["misses"] == []
