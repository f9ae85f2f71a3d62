"""A fresh install's first run compiles its kernels on both cores at once (hil.runtime.warmup), and the
run after it finds every kernel it calls in numba's cache: it compiles none."""

import os
import subprocess
import sys
import textwrap

import pytest

from hil import jit
from hil.jit import ahead

WORLD_TRANSPORT = "emu=firmware_sim.servers.transports:EmulatorTransport"  # as setup.py registers it

pytestmark = pytest.mark.skipif(not jit.COMPILED, reason="compiling is switched off (NUMBA_DISABLE_JIT=1)")

COUNT_MISSES = textwrap.dedent('''
    import importlib, json, pkgutil, sys
    from hil.jit import Kernel, ahead
    from hil.runtime import RunOptions, run
    from hil.runtime.warmup import marker, needed
    from hil.scenario import load_scenario

    before = needed()
    run(load_scenario(), RunOptions(out_root=None, duration_s=1.0))
    numba_loaded = "numba" in sys.modules
    misses = []
    for pkg in ("hil.vscmg", "hil.estimation", "hil.control", "hil.so3", "firmware_sim.world.models"):
        for info in pkgutil.walk_packages(importlib.import_module(pkg).__path__, pkg + "."):
            module = importlib.import_module(info.name)
            for name, obj in vars(module).items():
                dispatcher = getattr(obj, "_dispatcher", None) if isinstance(obj, Kernel) else None
                if dispatcher is not None and dispatcher.stats.cache_misses:
                    misses.append(f"{info.name}.{name}")
    print(json.dumps({"needed_before": before, "marker": marker().exists(), "misses": sorted(set(misses)),
                      "numba": numba_loaded, "ahead": ahead.loaded_modules()}))
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


def test_the_installs_warm_up_leaves_a_cache_from_which_the_first_run_compiles_nothing(tmp_path):
    """What an editable install runs (setup.py's ``warm_kernels``): the default scenario's kernels compiled
    with the built-in emulator's transport registered by hand (the build's tree has no entry points yet);
    the first run after it compiles no kernel and does not warm up again."""
    import json

    cache = str(tmp_path / "numba-cache")
    env = {**os.environ, "NUMBA_CACHE_DIR": cache}
    command = [sys.executable, "-m", "hil.runtime.warmup", "--install", f"--transport={WORLD_TRANSPORT}"]
    done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("kernels: compiled in "), done.stdout
    again = subprocess.run(command, capture_output=True, text=True, env=env, timeout=900)
    assert again.stdout.strip() == "kernels: in the cache already", again.stdout + again.stderr[-2000:]
    first = json.loads(_run(COUNT_MISSES, cache))
    assert not first["needed_before"] and first["misses"] == []
    if ahead.can_build():  # CI installs gcc and python3-dev (.ci/apt-packages)
        # the install built the kernels it warmed ahead of time (hil's, the world's): the run loads no numba
        assert len(first["ahead"]) == 2 and not first["numba"], first
        # and they give numba's bits: the same run through each, its telemetry compared byte for byte
        telemetry = {}
        for switch in ("0", "1"):
            out = tmp_path / f"runs-{switch}"
            command = [sys.executable, "-m", "hil", "run", "--no-plots", "--duration", "4", "--out", str(out)]
            done = subprocess.run(
                command, capture_output=True, text=True, env={**env, ahead.SWITCH: switch}, timeout=900
            )
            assert done.returncode == 0, done.stderr[-2000:]
            telemetry[switch] = next(out.glob("*/telemetry.csv")).read_bytes()
        assert telemetry["0"] == telemetry["1"] and len(telemetry["1"]) > 10_000
    else:
        assert first["ahead"] == [] and first["numba"], first
