"""numba's own cache files damaged beside a kernel (hil.jit's stamped cache): an index (``.nbi``) or an
entry (``.nbc``) cut short, emptied, overwritten or replaced by a directory — what a disk that filled, a
power cut after numba's rename or an interrupted copy of the cache leaves. The kernel's call is compiled
again and gives the reference's numbers, with a warning naming the cache folder; never numba's
``UnpicklingError``/``EOFError``/``IsADirectoryError`` out of the first call of every run. Each case runs
in a subprocess with its own ``NUMBA_CACHE_DIR`` (and no ahead-of-time build), so the tree's caches are
never touched."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil import jit

pytestmark = pytest.mark.skipif(not jit.COMPILED, reason="compiling is switched off (NUMBA_DISABLE_JIT=1)")

CALL = textwrap.dedent('''
    import json
    import numpy as np
    from hil.control import steering
    from hil.scenario import load_scenario

    scenario = load_scenario()
    geom = steering.VscmgSteering(scenario.spacecraft, scenario.loop.steering)._geom
    gam, w = np.array([[0.1, 0.2, 0.3, 0.4]]), np.array([[500.0, 510.0, 490.0, 505.0]])
    compiled, reference = np.zeros((1, 3)), np.zeros((1, 3))
    steering.momentum_rows(geom, gam, w, compiled)
    steering.momentum_rows.py_func(geom, gam, w, reference)
    stats = steering.momentum_rows.stats
    print(json.dumps({"compiled": compiled.tolist(), "reference": reference.tolist(),
                      "hits": sum(stats.cache_hits.values()), "misses": sum(stats.cache_misses.values())}))
''')  # fmt: skip


def _call(cache: Path) -> tuple[dict, str]:
    """The kernel called in a fresh interpreter on ``cache``: (what it printed, its stderr)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "VSCMG_HIL_AHEAD": "0"}
    done = subprocess.run([sys.executable, "-c", CALL], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cache holding the kernel, written by a first call."""
    cache = tmp_path_factory.mktemp("numba-cache")
    first, _ = _call(cache)
    assert first["misses"] == 1 and first["compiled"] == first["reference"]
    return cache


def _kernel_file(cache: Path, suffix: str) -> Path:
    (found,) = cache.glob(f"*/steering.momentum_rows-*{suffix}")
    return found


def _damage(path: Path, how: str, fraction: float, garbage: bytes) -> None:
    data = path.read_bytes()
    if how == "cut":
        path.write_bytes(data[: int(len(data) * fraction)])
    elif how == "overwritten":
        path.write_bytes(garbage)
    elif how == "directory":
        path.unlink()
        path.mkdir()


DAMAGE = st.tuples(
    st.sampled_from([".nbi", ".nbc"]),
    st.sampled_from(["cut", "overwritten", "directory"]),
    st.floats(min_value=0.0, max_value=0.999),
    st.binary(max_size=64),
)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(damage=DAMAGE)
def test_a_damaged_cache_file_is_compiled_again_with_a_warning(pristine: Path, tmp_path: Path, damage):
    suffix, how, fraction, garbage = damage
    cache = tmp_path / f"cache-{suffix[1:]}-{how}"
    shutil.rmtree(cache, ignore_errors=True)
    shutil.copytree(pristine, cache)
    damaged = _kernel_file(cache, suffix)
    _damage(damaged, how, fraction, garbage)
    result, stderr = _call(cache)
    assert result["compiled"] == result["reference"]
    assert "numba's cache" in stderr and str(damaged.parent) in stderr, stderr[-3000:]
    assert "Traceback" not in stderr, stderr[-3000:]


def test_a_cut_index_is_rewritten_and_the_next_process_loads_from_the_cache(pristine: Path, tmp_path: Path):
    """The damage heals: the compile after a cut index saves a good one, from which the next process loads
    the kernel (a cache hit, no warning)."""
    cache = tmp_path / "cache"
    shutil.copytree(pristine, cache)
    index = _kernel_file(cache, ".nbi")
    index.write_bytes(index.read_bytes()[:10])
    healed, stderr = _call(cache)
    assert healed["misses"] == 1 and "is not usable" in stderr
    again, stderr = _call(cache)
    assert again["hits"] == 1 and again["misses"] == 0 and "numba's cache" not in stderr, stderr[-3000:]
    assert again["compiled"] == again["reference"]
