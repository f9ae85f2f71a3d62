"""A stop signal whose exception Python drops ("Exception ignored") still stops the command.

A signal handler raises where the main thread is; in a ctypes callback (numba's LLVM object cache calls
one for each function it compiles), a ``__del__`` or a weakref callback, Python prints that exception and
drops it. A Ctrl-C during the first run's kernel compile was lost that way: a traceback on stderr, then the
run went on and said it completed, status 0. Each scenario runs in a subprocess (signals are not sent into
pytest's own process).
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from hil import jit

SITES = {
    "ctypes callback": """
        import ctypes
        callback = ctypes.CFUNCTYPE(None)(lambda: signal.raise_signal(SIGNUM))
        callback()
    """,
    "__del__": """
        class Finalised:
            def __del__(self):
                signal.raise_signal(SIGNUM)
        Finalised()
    """,
    "weakref callback": """
        import weakref
        class Target:
            pass
        target = Target()
        ref = weakref.ref(target, lambda _: signal.raise_signal(SIGNUM))
        del target
    """,
}


@pytest.mark.parametrize("site", sorted(SITES))
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_an_interrupt_dropped_in_a_callback_is_raised_after_it(site: str, signum: signal.Signals) -> None:
    """The signal's ``Interrupted`` reaches the code around the callback (a moment later), with its
    signal, and nothing is printed as ignored."""
    program = textwrap.dedent(
        """
        import signal, sys, time
        from hil.cli._signals import Interrupted, interrupts_raise
        SIGNUM = signal.Signals({signum})
        with interrupts_raise():
            try:
        {site}
                end = time.monotonic() + 10
                while time.monotonic() < end:  # the work after the callback (a compile goes on for seconds)
                    time.sleep(0.001)
                print("went on")
            except Interrupted as exc:
                print("interrupted by", signal.Signals(exc.signum).name)
        print("hook restored", sys.unraisablehook is sys.__unraisablehook__)
        """
    ).format(signum=int(signum), site=textwrap.indent(textwrap.dedent(SITES[site]), " " * 8))
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == [f"interrupted by {signum.name}", "hook restored True"], done.stdout
    assert "Exception ignored" not in done.stderr, done.stderr


def test_other_dropped_exceptions_are_still_printed() -> None:
    """Only interrupts are sent again: any other exception dropped in a callback is Python's to print."""
    program = textwrap.dedent(
        """
        from hil.cli._signals import interrupts_raise
        class Finalised:
            def __del__(self):
                raise ValueError("from __del__")
        with interrupts_raise():
            Finalised()
            print("went on")
        """
    )
    done = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "went on"
    assert "Exception ignored" in done.stderr and "from __del__" in done.stderr


@pytest.mark.slow
@pytest.mark.skipif(not jit.COMPILED, reason="compiling is switched off: a run compiles nothing")
@pytest.mark.parametrize("draw", range(2))
def test_ctrl_c_while_the_first_run_compiles_ends_it_interrupted(tmp_path: Path, draw: int) -> None:
    """``hil run`` on a fresh kernel cache, SIGINT at a drawn moment of its compile: the run says it was
    interrupted and exits 130, never completed."""
    delay = random.Random(draw).uniform(0.2, 3.0)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    out = str(tmp_path / "runs")
    command = [sys.executable, "-m", "hil", "run", "--no-plots", "--duration", "5", "--out", out]
    with subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as run:
        assert run.stderr is not None
        for line in run.stderr:
            if line.startswith("compiling the simulation kernels"):
                break
        else:
            pytest.fail("the run did not compile kernels on a fresh cache")
        time.sleep(delay)
        run.send_signal(signal.SIGINT)
        out, err = run.communicate(timeout=300)
    assert run.returncode == 130, (delay, out, err)
    assert "interrupted (SIGINT)" in err, (delay, err)
    assert "Exception ignored" not in err, (delay, err)
    assert "completed" not in out, (delay, out)
