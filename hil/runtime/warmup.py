"""Compiling a fresh install's kernels on both cores at once, before the first closed-loop run.

The compiled kernels (:mod:`hil.jit`) compile on their first call and are cached on disk; on a fresh
install (or after an edit of a kernel package) the first run pays for compiling them all: ~5–11 CPU s for
the world's (the plant step, the drive law, the simulated phone) and ~8 for the host's (the attitude
filter's chain, the variational step, steering), one after the other in one process. :func:`warm` splits
that in two: a child process compiles the world's by stepping a world of the run's scenario for a moment,
while this process compiles the host's by stepping the scenario's attitude filter and steering on
synthetic samples — the same objects, through the same calls, with the same argument types as the run,
so the run then finds every kernel in the cache (``tests/test_warmup.py`` checks that it compiles none).
A marker beside numba's cache, named after hil's kernel sources' stamp (:func:`hil.jit.tree_stamp`) and
numba's version, says that it was done; nothing happens once it exists, or when compiling is switched off
(``NUMBA_DISABLE_JIT=1``). An edit of the world's kernels alone (:mod:`firmware_sim.world.models`, stamped
with their own sources too) leaves the marker: a run then compiles those itself, as numba's stamp tells it.

The install's warm-up (``--install``) goes on: each side builds the kernels it called into an extension
module ahead of time (:func:`build_ahead`, :mod:`hil.jit.ahead`), so that a run loads no numba at all; a
run with hil's build of the present sources needs no warm-up either.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from hil import jit
from hil.jit import ahead
from hil.scenario import Scenario, parse_scenario

logger = logging.getLogger(__name__)

WORLD_WARM_S = 0.3
"""Board seconds of world stepped to compile its kernels (the board boots, the phone samples, the
drives run)."""


def marker() -> Path:
    """Where the 'kernels compiled' marker lives: numba's cache directory (``NUMBA_CACHE_DIR``) if set, else
    ``hil/jit/__pycache__`` (numba caches beside the sources there)."""
    import numba

    name = f"warm-{jit.tree_stamp()[:16]}-numba{numba.__version__}"
    return ahead.directory() / name


def needed() -> bool:
    """Whether a run would compile kernels first: hil's kernels have no ahead-of-time build of these sources
    (:mod:`hil.jit.ahead`) and there is no marker for them yet (numba is imported only to ask the latter)."""
    return jit.COMPILED and not ahead.available(None) and not marker().exists()


def warm(
    scenario: Scenario, transports: Mapping[str, str] | None = None, ahead_of_time: bool = False
) -> float | None:
    """Compile the kernels the run of ``scenario`` needs, world and host in parallel; the seconds it took,
    or None if there was nothing to do. A child that fails is logged, never fatal: the run then compiles
    what is missing itself. ``transports`` (scheme → ``"module:factory"``) are registered in the world's
    child first: for a tree not installed yet, whose entry points do not resolve (the install's build).
    With ``ahead_of_time`` (the install's), each side then also builds the kernels it called into an
    extension module where there is no build of the present sources yet (:func:`build_ahead`). Nothing
    when compiling is switched off (``NUMBA_DISABLE_JIT=1``): there is nothing to compile or build, and
    stepping the world and the filter as plain Python would only take time."""
    if not jit.COMPILED or (not needed() and not ahead_of_time):
        return None
    start = time.monotonic()
    was_needed = needed()
    registrations = [f"--transport={scheme}={target}" for scheme, target in (transports or {}).items()]
    child_options = [*registrations, *(["--ahead"] if ahead_of_time else [])]
    built: list[str] = []
    with tempfile.TemporaryFile() as err, tempfile.TemporaryFile() as out:
        child = subprocess.Popen(
            [sys.executable, "-m", "hil.runtime.warmup", *child_options],
            stdin=subprocess.PIPE,
            stdout=out,
            stderr=err,
        )
        try:
            assert child.stdin is not None
            with child.stdin:
                child.stdin.write((scenario.source or _default_source()).encode())
            warm_host(scenario)
            if ahead_of_time:
                built += [str(path) for path in build_ahead(lambda home: home is None)]
        finally:
            child.wait()
        out.seek(0)
        built += out.read().decode("utf-8", "replace").split()
        if child.returncode != 0:
            err.seek(0)
            logger.warning(
                "compiling the world's kernels failed (the run compiles them): %s",
                err.read().decode("utf-8", "replace")[-500:],
            )
            return time.monotonic() - start
    if not was_needed and not built:
        return None
    try:
        path = marker()
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"compiled in {time.monotonic() - start:.1f} s\n")
    except OSError as exc:  # a read-only cache location: numba falls back to another, the marker cannot
        logger.info("cannot write the kernel marker %s: %s", exc.filename, exc.strerror)
    return time.monotonic() - start


def build_ahead(wanted: Callable[[str | None], bool]) -> list[Path]:
    """Build ahead of time (:func:`hil.jit.ahead.build`) the kernels of each ``wanted`` home called in this
    process whose build of the present sources is missing; the modules built. A failure (no C compiler,
    a compiler error) is logged and leaves that home to numba: an install never fails for it."""
    homes: dict[str | None, list[jit.Kernel]] = {}
    for kernel in jit.kernels():
        homes.setdefault(jit.home(kernel.py_func), []).append(kernel)
    built = []
    for home, kernels in homes.items():
        if not wanted(home) or ahead.available(home):
            continue
        if not ahead.can_build():
            logger.warning(
                "no C compiler or Python headers: %s's kernels are compiled by numba when first used",
                home or "hil",
            )
            break
        try:
            path = ahead.build(home, kernels)
        except Exception as exc:  # whatever numba.pycc or the compiler raises: numba's JIT remains
            logger.warning("building %s's kernels ahead of time failed: %s", home or "hil", exc)
            continue
        if path is not None:
            built.append(path)
    return built


def _default_source() -> str:
    """A scenario built in code has no TOML: the world's kernels are the same for any, so the default's."""
    from hil.scenario import load_scenario

    return load_scenario().source


def warm_host(scenario: Scenario) -> None:
    """Step the scenario's attitude filter (through the multi-rate merger, as the host does) and its steering
    law once each, with samples and states of the run's types."""
    from hil.bounded_estimator import with_bounded_calls
    from hil.control.steering import VscmgSteering
    from hil.estimation.multirate import Merger
    from hil.estimation.sensors import SensorKind, SensorSample

    estimator = with_bounded_calls(scenario.make_estimator())  # a user's first step may block, as in a run
    merger = Merger()
    field = np.asarray(scenario.phone.field_enu_uT, dtype=float)
    readings: dict[SensorKind, tuple[float, float, float]] = {
        SensorKind.GYR: (0.01, -0.02, 0.03),
        SensorKind.ACC: (0.1, 0.2, 9.8),
        SensorKind.MAG: (float(field[0]), float(field[1]), float(field[2])),
    }
    for k in range(40):
        for kind, xyz in readings.items():
            sample = SensorSample(0.005 * k, kind, xyz)
            for step in merger.push(sample):
                estimator.step(step)
    steering = VscmgSteering(scenario.spacecraft, scenario.loop.steering)
    n = scenario.n_units
    gimbal = np.linspace(0.1, 0.4, n)
    rotor = np.full(n, scenario.spacecraft.nominal_rotor_speed)
    steering.momentum(gimbal, rotor)
    steering.delta(gimbal, rotor)
    steering.solve(np.array([1e-4, -2e-4, 5e-5]), gimbal, rotor, 1.0 / scenario.loop.control_rate_hz)


def warm_world(scenario: Scenario) -> None:
    """Step the scenario's simulated world (the built-in emulator's board with its plant, drives and
    phone) for :data:`WORLD_WARM_S` board seconds."""
    from hil.link.transports import InProcessBoard, create_transport
    from hil.timing.clock import LockstepClock

    link = create_transport(scenario.emulator_url())
    assert isinstance(link, InProcessBoard)
    clock = LockstepClock()
    link.bind_clock(clock)
    world = link.open_world(scenario)
    while clock.now() < WORLD_WARM_S:
        clock.advance(0.01)
        world.advance_to(clock.now())
    world.truth()


def load_kernels(scenario: Scenario, world: bool) -> None:
    """Load the compiled kernels a run calls into this process before the board is armed (with ``world``:
    the simulated world's too).

    A kernel is loaded from numba's on-disk cache (or compiled) on its first call: ~0.35 s for the host's
    on an idle 2-core machine, 0.7 s loaded. Left to a wall-clock run, the estimator's came with the first
    phone samples after arming and steering's with the first slew tick: each stalled the control task past
    the board's 0.25 s link timeout, and the board failed safe (issue 16, finding 7). A lockstep run loads
    them first as well: start-up, not time in its run loop. Once per process and scenario: a campaign's
    worker runs many (a world's warm-up costs ~0.05 s)."""
    key = (scenario.source, world)
    if key in _LOADED:
        return
    warm_host(scenario)
    if world:
        warm_world(scenario)
    _LOADED.add(key)


_LOADED: set[tuple[str, bool]] = set()
"""(scenario TOML, with the world) pairs whose kernels :func:`load_kernels` has loaded in this process."""


def _main(argv: Sequence[str] | None = None) -> int:
    """The world's child (the scenario's TOML on stdin, its world's kernels compiled), or with
    ``--install`` the install's warm-up of the default scenario (world and host, the marker written)."""
    import argparse

    from hil.link.transports import register

    parser = argparse.ArgumentParser(prog="python -m hil.runtime.warmup")
    parser.add_argument("--install", action="store_true", help="warm the default scenario's kernels")
    parser.add_argument(
        "--ahead", action="store_true", help="(the world's child) also build its kernels ahead of time"
    )
    parser.add_argument(
        "--transport",
        action="append",
        default=[],
        metavar="SCHEME=MODULE:FACTORY",
        help="register a transport first (a tree whose entry points are not installed yet)",
    )
    args = parser.parse_args(argv)
    transports = dict(entry.split("=", 1) for entry in args.transport)
    for scheme, target in transports.items():
        register(scheme, target)
    if args.install:
        from hil.scenario import load_scenario

        took = warm(load_scenario(), transports, ahead_of_time=True)
        if not jit.COMPILED:  # not "in the cache already": nothing is compiled, nor needs to be
            sys.stdout.write("kernels: not compiled (compiling is switched off: NUMBA_DISABLE_JIT=1)\n")
            return 0
        said = "in the cache already" if took is None else f"compiled in {took:.1f} s"
        sys.stdout.write(f"kernels: {said}\n")
        return 0 if not needed() else 1
    warm_world(parse_scenario(sys.stdin.read()))
    if args.ahead:
        for path in build_ahead(lambda home: home is not None):
            sys.stdout.write(f"{path}\n")
    return 0


if __name__ == "__main__":
    sys.exit(_main())
