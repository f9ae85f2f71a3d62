"""Build configuration beyond pyproject.toml: the optional C extension ``protocol._speedups``, and an
editable install's compiled kernels.

Everything else (metadata, dependencies, packages) is in pyproject.toml. The extension is COBS and
CRC-16 in C for the frame codec (protocol/speedups.py); ``optional=True`` lets a machine without a C
compiler install the package anyway, and then the codec runs on the pure-Python reference.

An editable install (``pip install -e .``, the README's) also compiles the numba kernels a default run
needs into numba's cache beside the sources (``hil.runtime.warmup``, world and host on two processes), so
that the first ``hil run`` does not spend ~10 s compiling first. That needs numba and what the kernels
import in the build's environment (pyproject.toml's ``build-system.requires``), and it only helps when
that numba is the one the install then gets (numba ignores a cache of another version): a failure or a
mismatch costs nothing but the compile at the first run, as without this step. A regular (wheel) install
skips it: the cache would not travel with the wheel. ``VSCMG_HIL_NO_INSTALL_WARM=1`` skips it too.

An editable install also compiles the packages' bytecode (``__pycache__`` beside the sources), as pip
does for a regular install: without it, a machine whose environment says ``PYTHONDONTWRITEBYTECODE=1``
(this project's CI and development machines do) compiled every module from source in every process —
~0.2 s of each ``hil run``'s start, each campaign worker's and each test's subprocess (issue 29). Python
checks each ``.pyc`` against its source's time stamp, so an edited module is compiled afresh, as before.
"""

import os
import subprocess
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent

WORLD_TRANSPORT = "emu=firmware_sim.servers.transports:EmulatorTransport"
"""The built-in emulator's transport, as pyproject.toml's entry point declares it: the tree being built is
not installed yet, so its entry points do not resolve."""


def warm_kernels() -> None:
    """Compile the default run's kernels into numba's cache beside the sources; never fails the build."""
    if os.environ.get("VSCMG_HIL_NO_INSTALL_WARM") == "1":
        return
    path = os.environ.get("PYTHONPATH")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), *([path] if path else [])]))
    command = [sys.executable, "-m", "hil.runtime.warmup", "--install", f"--transport={WORLD_TRANSPORT}"]
    try:
        done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    except (OSError, subprocess.TimeoutExpired) as exc:
        _say(f"kernels not compiled at install ({exc}); the first run compiles them")
        return
    said = (done.stdout + done.stderr).strip().splitlines()
    if done.returncode == 0:
        _say(said[-1] if said else "kernels compiled")
    else:
        _say(f"kernels not compiled at install ({' | '.join(said[-3:])}); the first run compiles them")


PACKAGES = ("protocol", "hil", "firmware_sim")
"""The packages whose bytecode an editable install compiles (:func:`compile_bytecode`)."""


def compile_bytecode() -> None:
    """Compile the packages' modules to ``__pycache__`` beside the sources; never fails the build."""
    import compileall

    try:
        done = all(compileall.compile_dir(ROOT / package, quiet=1) for package in PACKAGES)
    except OSError as exc:  # a read-only tree: every process compiles in memory, as without this step
        _say(f"bytecode not compiled at install ({exc})")
        return
    if not done:
        _say("bytecode not compiled at install for every module (a syntax error?)")


def _say(text: str) -> None:
    sys.stderr.write(f"vscmg-hil: {text}\n")


class BuildPyWithKernels(build_py):
    """``build_py``, then, in an editable install, :func:`warm_kernels`."""

    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            compile_bytecode()
            warm_kernels()


setup(
    cmdclass={"build_py": BuildPyWithKernels},
    ext_modules=[
        Extension(
            "protocol._speedups",
            sources=["protocol/_speedups.c"],
            extra_compile_args=["-O2"],
            optional=True,
        )
    ],
)
