"""An ahead-of-time build (hil.jit.ahead) damaged beside its table: the extension module cut short (a disk
that filled, a power cut after the rename, an interrupted copy), a byte of it changed, or left beside
another build's table (a build interrupted between its module and its table). Each is refused by name
before it is loaded — logged, the kernel run through numba with the reference's numbers — never a
process killed by SIGBUS at its first kernel call, never a changed module's numbers. Built once into a
temporary ``NUMBA_CACHE_DIR``; each case in a subprocess (a SIGBUS would end pytest's own process)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil import jit
from hil.jit import ahead

pytestmark = [
    pytest.mark.skipif(not jit.COMPILED, reason="compiling is switched off (NUMBA_DISABLE_JIT=1)"),
    pytest.mark.skipif(not ahead.can_build(), reason="no C compiler or Python headers to build with"),
]

SETUP = """
import json, sys
import numpy as np
from hil.control import steering
from hil.jit import ahead
from hil.scenario import load_scenario

scenario = load_scenario()
geom = steering.VscmgSteering(scenario.spacecraft, scenario.loop.steering)._geom
gam, w = np.array([[0.1, 0.2, 0.3, 0.4]]), np.array([[500.0, 510.0, 490.0, 505.0]])
compiled, reference = np.zeros((1, 3)), np.zeros((1, 3))
"""

BUILD = SETUP + textwrap.dedent('''
    steering.momentum_rows(geom, gam, w, compiled)  # through numba: what the build exports
    print(ahead.build(None, [steering.momentum_rows]))
''')  # fmt: skip

CALL = SETUP + textwrap.dedent('''
    steering.momentum_rows(geom, gam, w, compiled)
    steering.momentum_rows.py_func(geom, gam, w, reference)
    print(json.dumps({"compiled": compiled.tolist(), "reference": reference.tolist(),
                      "ahead": ahead.loaded_modules(), "numba": "numba" in sys.modules}))
''')  # fmt: skip


def _python(code: str, cache: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    env.pop(ahead.SWITCH, None)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)


def _call(cache: Path) -> tuple[dict, str]:
    done = _python(CALL, cache)
    assert done.returncode == 0, (
        f"exit {done.returncode}"
        + (f" ({signal.Signals(-done.returncode).name})" if done.returncode < 0 else "")
        + f": {done.stderr[-3000:]}"
    )
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cache folder holding hil's build of one kernel (steering's ``momentum_rows``), which loads."""
    cache = tmp_path_factory.mktemp("ahead")
    done = _python(BUILD, cache)
    assert done.returncode == 0 and done.stdout.strip().endswith(".so"), done.stderr[-3000:]
    result, _ = _call(cache)
    assert result["ahead"] and result["compiled"] == result["reference"], result
    return cache


def _library(cache: Path) -> Path:
    (found,) = cache.glob(f"{ahead.PREFIX}hil_*.so")
    return found


DAMAGE = st.one_of(
    st.tuples(st.just("cut"), st.floats(min_value=0.0, max_value=0.999)),
    st.tuples(st.just("byte changed"), st.floats(min_value=0.0, max_value=0.999)),
)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(damage=DAMAGE)
def test_a_damaged_module_is_refused_by_name_and_numba_runs_the_kernel(built: Path, tmp_path: Path, damage):
    how, where = damage
    cache = tmp_path / "cache"
    shutil.rmtree(cache, ignore_errors=True)
    shutil.copytree(built, cache)
    library = _library(cache)
    data = bytearray(library.read_bytes())
    at = int(len(data) * where)
    if how == "cut":
        del data[at:]
    else:
        data[at] ^= 0x5A
    library.write_bytes(bytes(data))
    result, stderr = _call(cache)
    assert result["ahead"] == [] and result["compiled"] == result["reference"], result
    assert "is not usable" in stderr and library.name in stderr, stderr[-3000:]


def test_a_module_beside_another_builds_table_is_refused(built: Path, tmp_path: Path):
    """A build interrupted after its module was replaced and before its table was: the module is not the
    one the table describes (here: the table of a build of the same name whose exports were made in
    another order, so that ``k0`` would be another function), and is not loaded."""
    cache = tmp_path / "cache"
    shutil.copytree(built, cache)
    library = _library(cache)
    table_path = library.with_name(library.name.split(".")[0] + ahead.TABLE_SUFFIX)
    document = json.loads(table_path.read_text())
    document.setdefault("library", {})["sha256"] = "0" * 64  # another build's module, of the same size
    table_path.write_text(json.dumps(document))
    result, stderr = _call(cache)
    assert result["ahead"] == [] and result["compiled"] == result["reference"], result
    assert "SHA-256" in stderr and library.name in stderr, stderr[-3000:]
