"""``hil run`` reaches its first tick without the heavy libraries it does not use (issue 29): each check runs
in a fresh interpreter (a subprocess) and reads its ``sys.modules``, so an eager import added anywhere on
the path (a package ``__init__``, a module-level import in hil.cli, hil.runtime, hil.link) fails here.

Plotting (matplotlib), campaigns (Dask, distributed, tornado), the browser tests (selenium) and scipy's
linear algebra (which numba's BLAS probe would pull in: :class:`hil.jit._BlasProbeDeclined`) are loaded
where they are used, never on the way to a run's first tick.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

HEAVY = ("matplotlib", "dask", "distributed", "tornado", "selenium", "pandas", "scipy.linalg")
"""Modules no run needs before its first tick."""


def _loaded(
    code: str, timeout_s: float = 240.0, env_extra: dict[str, str] | None = None
) -> dict[str, object]:
    """Run ``code`` in a fresh interpreter from the checkout's root (its environment with ``env_extra``);
    it prints one JSON object last."""
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=ROOT,
        env={**os.environ, **(env_extra or {})},
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def _heavy_check(before: str) -> str:
    return f"""
        import json, sys
        {before}
        print(json.dumps({{"heavy": sorted(m for m in {HEAVY!r} if m in sys.modules),
                           "numba": "numba" in sys.modules}}))
    """


def test_the_run_loop_imports_none_of_the_heavy_libraries_nor_numba():
    """Importing the run's modules (every kernel module among them) imports no numba: a kernel imports it
    when it is first called without an ahead-of-time build (:class:`hil.jit.Kernel`)."""
    loaded = _loaded(_heavy_check("import hil.runtime.loop, hil.cli.run, hil.link.sources.simulated"))
    assert loaded == {"heavy": [], "numba": False}


LIGHTER = ("protocol.can", "importlib.resources", "tempfile", "shutil", "subprocess")
"""Smaller modules the imports before a run's first tick left out (a few ms each, ~12 ms with the codecs
below: the ≤ 0.3 s of issue 29): CAN's framing (a run over CAN imports it), importlib's resources and the
temporary files and shutil only the install's builds use, subprocess (a summary's git revision asks)."""


def test_the_run_modules_import_no_can_framing_no_tempfile_no_subprocess_and_generate_no_codec():
    """The modules the runtime bench times (``bench/bench_runtime.py``'s imports before the first tick)
    load none of :data:`LIGHTER` and generate no message codec; a frame's first encode or decode generates
    its message's alone, which then encodes and decodes as the reference does."""
    loaded = _loaded(
        f"""
        import json, sys
        import hil.cli, hil.cli.run, hil.runtime, hil.scenario, firmware_sim.servers.transports
        import firmware_sim.world
        from protocol.messages import CODECS
        lighter = sorted(m for m in {LIGHTER!r} if m in sys.modules)
        made_at_import = sorted(CODECS._made)
        from protocol import Arm, decode_frame, encode_frame
        frame = decode_frame(encode_frame(Arm(), 7)[:-1])
        print(json.dumps({{"lighter": lighter, "made": made_at_import, "after": sorted(CODECS._made),
                           "frame": [type(frame.message).__name__, frame.seq], "arm": Arm.MSG_ID}}))
        """
    )
    assert loaded["lighter"] == [] and loaded["made"] == []
    assert loaded["after"] == [loaded["arm"]] and loaded["frame"] == ["Arm", 7]


def test_building_the_command_line_does_not_import_numba():
    """``hil run --help`` (every command's parser) is argparse and the command modules: no scenario
    package, no numba, no numpy-heavy stack (hil.cli's docstring), and no ``importlib.metadata`` (10-30 ms:
    the version ``hil --version`` and a run's summary show, the registries' entry points, are read when
    asked for)."""
    loaded = _loaded(_heavy_check("from hil.cli import build_parser; build_parser()"))
    assert loaded == {"heavy": [], "numba": False}
    assert _loaded(
        "import json, sys; from hil.cli import build_parser; build_parser(); "
        "print(json.dumps({'metadata': 'importlib.metadata' in sys.modules}))"
    ) == {"metadata": False}


def test_the_command_lines_module_imports_no_numpy_and_no_run_modules():
    """``import hil.cli`` runs before hil's signal handlers are in place (``hil.cli.entry`` installs them,
    then builds the parser): a Ctrl-C in it meets Python's own handler (a traceback; a SIGHUP right after
    it killed the process). It once imported the run loop through ``hil.runtime``'s package file (~0.3 s:
    numpy, the host, the board client); a run's modules now come in its command, under hil's handlers."""
    loaded = _loaded(
        """
        import json, sys
        import hil.cli
        print(json.dumps(sorted(m for m in ("numpy", "hil.runtime.host", "hil.runtime.loop",
                                            "hil.link.board") if m in sys.modules)))
        """
    )
    assert loaded == []


def test_numbas_blas_probe_does_not_load_scipy_linalg_and_scipy_still_imports():
    """numba's target loads numba.np.arraymath on a kernel's first call; its BLAS probe is declined (no
    scipy.linalg), once: an import of scipy.linalg afterwards works, and the guard is gone."""
    loaded = _loaded(
        """
        import json, sys
        import hil.jit, numba.np.arraymath as arraymath
        probe_loaded = "scipy.linalg" in sys.modules
        guard_left = any(type(f).__name__ == "_BlasProbeDeclined" for f in sys.meta_path)
        import scipy.linalg.cython_blas
        print(json.dumps({"probe_loaded": probe_loaded, "have_blas": arraymath._HAVE_BLAS,
                          "guard_left": guard_left, "later": "scipy.linalg" in sys.modules}))
        """
    )
    assert loaded == {"probe_loaded": False, "have_blas": False, "guard_left": False, "later": True}


def test_a_scipy_linalg_loaded_first_is_left_alone():
    """With scipy.linalg already imported the guard is not installed: numba's probe finds its BLAS."""
    loaded = _loaded(
        """
        import json, sys
        import scipy.linalg
        import hil.jit, numba.np.arraymath as arraymath
        print(json.dumps({"have_blas": arraymath._HAVE_BLAS,
                          "guard": any(type(f).__name__ == "_BlasProbeDeclined" for f in sys.meta_path)}))
        """
    )
    assert loaded == {"have_blas": True, "guard": False}


def test_a_default_run_reaches_its_first_tick_without_the_heavy_libraries(tmp_path):
    """The real path: ``hil run --no-plots`` (lockstep, the built-in emulator: scenario, kernels loaded,
    world, board link, phone source), ``sys.modules`` read at the host's first control tick. With the
    install's ahead-of-time builds of the present sources (CI's install makes them: hil.jit.ahead), that
    includes numba and LLVM: the run's kernels are all in the builds."""
    loaded = _loaded(
        f"""
        import json, sys
        from hil.cli import main
        from hil.jit import ahead
        from hil.runtime.host import Host

        seen = {{"built": ahead.available(None) and ahead.available("firmware_sim.world.models")}}
        tick = Host.tick

        def first_tick(self, t, *rest):
            if "heavy" not in seen:
                seen["heavy"] = sorted(m for m in {HEAVY!r} if m in sys.modules)
                seen["numba"] = sorted(m for m in ("numba", "llvmlite") if m in sys.modules)
            return tick(self, t, *rest)

        Host.tick = first_tick
        main(["run", "--no-plots", "--duration", "1", "--out", {str(tmp_path)!r}])
        print(json.dumps(seen))
        """
    )
    assert loaded["heavy"] == []
    if loaded["built"] or os.environ.get("VSCMG_HIL_REQUIRE_ALL") == "1":
        assert loaded["numba"] == [], loaded


def test_the_run_modules_are_loaded_from_the_installs_bytecode_not_compiled_from_source():
    """An editable install compiles the packages' bytecode (setup.py's ``compile_bytecode``), so a process
    whose environment says ``PYTHONDONTWRITEBYTECODE=1`` (CI's, this project's machines') does not compile
    every module from source at every start (~0.2 s of each ``hil run``'s, issue 29). Read in a fresh
    interpreter with that setting: the run's modules compiled from source are only those edited since
    their bytecode was written (none on CI, which tests what it has just installed)."""
    loaded = _loaded(
        """
        import importlib.util, json, os, sys
        from importlib._bootstrap_external import SourceLoader
        compiled = []
        to_code = SourceLoader.source_to_code
        def counting(self, data, path, *args, **kwargs):
            compiled.append(str(path))
            return to_code(self, data, path, *args, **kwargs)
        SourceLoader.source_to_code = counting
        import hil.cli, hil.cli.run, hil.runtime, hil.scenario, firmware_sim.servers.transports
        import firmware_sim.world
        ours = [p for p in compiled if "/site-packages/" not in p]
        def stale(path):
            try:
                pyc = open(importlib.util.cache_from_source(path), "rb").read(16)
            except OSError:
                return True
            st = os.stat(path)
            mtime, size = int.from_bytes(pyc[8:12], "little"), int.from_bytes(pyc[12:16], "little")
            return (mtime, size) != (int(st.st_mtime) & 0xFFFFFFFF, st.st_size & 0xFFFFFFFF)
        modules = [m.__file__ for m in list(sys.modules.values())
                   if (getattr(m, "__file__", None) or "").startswith(os.getcwd())
                   and m.__file__.endswith(".py") and "/site-packages/" not in m.__file__]
        print(json.dumps({"ours": ours, "stale": sorted(p for p in modules if stale(p)),
                          "modules": len(modules), "dont_write": sys.dont_write_bytecode}))
        """,
        env_extra={"PYTHONDONTWRITEBYTECODE": "1"},
    )
    assert loaded["dont_write"] is True and loaded["modules"] > 100
    assert sorted(loaded["ours"]) == loaded["stale"]  # compiled from source: exactly the edited ones
    if os.environ.get("VSCMG_HIL_REQUIRE_ALL") == "1":
        assert loaded["ours"] == [], loaded["ours"][:5]
