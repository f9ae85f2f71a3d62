"""Where a default ``hil run`` spends its time: the host's share against the world's, per control tick and
per estimator step (issue 29's profile, docs/compiled.md "Profile").

``python -m bench.profile_run`` runs ``hil run --no-plots`` (lockstep, the built-in emulator, cubesat-1u)
in this process twice over:

- **timed** (no profiler): perf_counter around the run loop (:func:`hil.runtime.loop._run_scheduler`), the
  world (:meth:`firmware_sim.world.World.advance_to`, everything the far side does: plant, drives, phone,
  board), the host's control tick (:meth:`hil.runtime.host.Host.tick`) and its estimator task
  (:meth:`hil.runtime.host.Host.feed`). The host's share is the loop minus the world (the board link's
  service and the scheduler are the host's). Wrapping costs ~0.3 µs per call on each side alike.
- **profiled** (``--profile FILE``): cProfile over the whole command, its top functions by own time, each
  marked host, world or protocol by where it lives. cProfile inflates every Python call (2–3× here), so
  its times rank the functions; the timed run gives the costs.
- **first tick** (``--first-tick``): a fresh ``python -X importtime`` process up to the host's first
  control tick: wall time from spawn, the imports on the way, and which heavy libraries are loaded.

Counts (calls per tick, per step) are exact and load-independent; times on a shared machine are not, so
compare two trees by alternating them in one session (``--repeat``).
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import pstats
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
WORLD_SIDE = "firmware_sim/"
HOST_SIDE = "hil/"
SHARED = "protocol/"
"""Where each side's code lives (relative to the checkout): ``protocol/`` is both sides' (the board
emulator's pulse calibration and telemetry encoding too), marked ``proto``."""


def _short(filename: str) -> str:
    """A profiled function's file relative to the checkout, or to site-packages for a library's."""
    path = Path(filename)
    if path.is_relative_to(ROOT):
        return str(path.relative_to(ROOT))
    return filename.split("site-packages/")[-1]


@dataclass
class Stopwatch:
    """Accumulated wall time (s) and calls of one wrapped function."""

    seconds: float = 0.0
    calls: int = 0

    def wrap(self, fn: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start
                self.calls += 1

        return timed


@dataclass
class Timing:
    """One timed run's figures (s, calls)."""

    loop: Stopwatch = field(default_factory=Stopwatch)
    world: Stopwatch = field(default_factory=Stopwatch)
    tick: Stopwatch = field(default_factory=Stopwatch)
    feed: Stopwatch = field(default_factory=Stopwatch)
    estimator_steps: int = 0
    command_s: float = 0.0

    def lines(self) -> list[str]:
        host = self.loop.seconds - self.world.seconds
        steps = max(self.estimator_steps, 1)
        ticks = max(self.tick.calls, 1)
        return [
            f"whole command {self.command_s:.2f} s; run loop {self.loop.seconds:.3f} s",
            f"world (World.advance_to, {self.world.calls} calls) {self.world.seconds:.3f} s "
            f"({100 * self.world.seconds / self.loop.seconds:.0f}% of the loop)",
            f"host (loop - world) {host:.3f} s ({100 * host / self.loop.seconds:.0f}%)",
            f"Host.tick {self.tick.calls} ticks, {1e6 * self.tick.seconds / ticks:.1f} µs/tick",
            f"Host.feed {self.feed.calls} calls, {self.estimator_steps} estimator steps, "
            f"{1e6 * self.feed.seconds / steps:.1f} µs/step (admission, merge, filter step)",
        ]


PARTS = (
    ("hil.link.board.client", "BoardClient", "service"),
    ("hil.runtime.host", "Host", "_control"),
    ("hil.runtime.control_step", "ControlStep", "step"),
    ("hil.control.attitude", "AttitudeController", "update_floats"),
    ("hil.control.steering", "VscmgSteering", "momentum_one"),
    ("hil.control.steering", "VscmgSteering", "solve_one"),
    ("hil.control.motor_loops", "SetpointGenerator", "update_floats"),
    ("hil.runtime.host", "Host", "_send"),
    ("hil.runtime.host", "Host", "_snapshot"),
    ("hil.runtime.rows", "TickRecorder", "record"),
    ("hil.runtime.telemetry", "TelemetrySchema", "row"),
    ("hil.runtime.runlog", "CsvLog", "write_values"),
    ("hil.runtime.actuators", "ActuatorWatch", "following"),
    ("hil.runtime.phone_clock", "PhoneClock", "admit"),
    ("hil.estimation.multirate", "Merger", "push"),
    ("hil.estimation.filter", "AttitudeFilter", "step"),
)
"""The parts of the host's tick and estimator task timed with ``--parts`` (module, class, method): the
control tick's float path (:meth:`hil.runtime.control_step.ControlStep.step`), not the batched calls its
oracle makes."""


def parts_run() -> dict[str, Stopwatch]:
    """One ``hil run --no-plots`` with a stopwatch on each of :data:`PARTS` (nested parts include their
    callees; wrapping adds ~0.3 µs a call)."""
    import importlib

    from hil.cli import main

    watches: dict[str, Stopwatch] = {}
    restore: list[tuple[type, str, Any]] = []
    for module, cls_name, method in PARTS:
        cls = getattr(importlib.import_module(module), cls_name)
        watch = watches[f"{cls_name}.{method}"] = Stopwatch()
        restore.append((cls, method, cls.__dict__[method]))
        setattr(cls, method, watch.wrap(cls.__dict__[method]))
    try:
        with tempfile.TemporaryDirectory() as out, contextlib.redirect_stdout(io.StringIO()):
            main(_argv(out))
    finally:
        for cls, method, original in restore:
            setattr(cls, method, original)
    return watches


FIRST_TICK = "first tick"
"""What the child of :func:`first_tick` prints at the host's first control tick."""

_FIRST_TICK_CHILD = """
import os, sys
from hil.cli import main
from hil.runtime.host import Host

def first_tick(self, t, *rest):
    heavy = sorted(m for m in ("matplotlib", "dask", "distributed", "tornado", "selenium", "scipy.linalg")
                   if m in sys.modules)
    print("first tick", len(sys.modules), "modules; heavy:", heavy, flush=True)
    os._exit(0)

Host.tick = first_tick
main(["run", "--no-plots", "--out", sys.argv[1]])
"""


def first_tick() -> tuple[float, float, str]:
    """A fresh ``python -X importtime`` process running ``hil run --no-plots`` up to the host's first
    control tick (it exits there): (wall s from spawn to that tick, s of imports on the way, the child's
    line: modules loaded and which heavy ones)."""
    import subprocess
    import sys

    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-X", "importtime", "-c", _FIRST_TICK_CHILD, out],
            capture_output=True,
            text=True,
            check=True,
            cwd=ROOT,
        )
        wall = time.perf_counter() - start
    imports_us = 0
    for line in done.stderr.splitlines():
        parts = line.split("|")
        if line.startswith("import time:") and len(parts) == 3 and parts[1].strip().isdigit():
            if not parts[2].startswith("  "):  # top level: its cumulative time covers its children
                imports_us += int(parts[1])
    said = next(line for line in done.stdout.splitlines() if line.startswith(FIRST_TICK))
    return wall, imports_us / 1e6, said


def _argv(out: str) -> list[str]:
    return ["run", "--no-plots", "--out", out]


def timed_run() -> Timing:
    """One ``hil run --no-plots`` with the stopwatches in place (restored after)."""
    from firmware_sim.world import World
    from hil.cli import main
    from hil.runtime import host as host_module
    from hil.runtime import loop as loop_module

    timing = Timing()
    originals = (loop_module._run_scheduler, World.advance_to, host_module.Host.tick, host_module.Host.feed)
    loop_module._run_scheduler = timing.loop.wrap(originals[0])  # type: ignore[assignment]
    World.advance_to = timing.world.wrap(originals[1])  # type: ignore[method-assign]
    host_module.Host.tick = timing.tick.wrap(originals[2])  # type: ignore[method-assign]
    steps_seen: list[Any] = []
    feed = originals[3]

    def counted_feed(self: Any, samples: Any, now: Any = None) -> None:
        feed(self, samples, now)
        steps_seen[:] = [self.counters.estimator_steps]

    host_module.Host.feed = timing.feed.wrap(counted_feed)  # type: ignore[method-assign]
    try:
        with tempfile.TemporaryDirectory() as out:
            start = time.perf_counter()
            with contextlib.redirect_stdout(io.StringIO()):
                main(_argv(out))
            timing.command_s = time.perf_counter() - start
    finally:
        loop_module._run_scheduler = originals[0]  # type: ignore[assignment]
        World.advance_to, host_module.Host.tick, host_module.Host.feed = originals[1:]  # type: ignore[method-assign]
    timing.estimator_steps = steps_seen[0] if steps_seen else 0
    return timing


def profiled_run(path: str, top: int) -> str:
    """One ``hil run --no-plots`` under cProfile, written to ``path``; the top ``top`` functions by own
    time, each marked ``world`` (firmware_sim), ``host`` (hil), ``proto`` (protocol, either side's) or ``-``
    (builtins, libraries)."""
    from hil.cli import main

    with tempfile.TemporaryDirectory() as out:
        profiler = cProfile.Profile()
        with contextlib.redirect_stdout(io.StringIO()):
            profiler.runcall(main, _argv(out))
    profiler.dump_stats(path)
    stats = pstats.Stats(path, stream=io.StringIO())
    rows = sorted(stats.stats.items(), key=lambda kv: kv[1][2], reverse=True)[:top]  # type: ignore[attr-defined]
    lines = [f"{'own s':>7} {'calls':>8} {'µs/call':>8}  side   function"]
    for (filename, line, name), (_cc, calls, own, _cum, _callers) in rows:
        where = _short(filename)
        sides = ((WORLD_SIDE, "world"), (HOST_SIDE, "host"), (SHARED, "proto"))
        side = next((name for prefix, name in sides if where.startswith(prefix)), "-")
        per_call = 1e6 * own / max(calls, 1)
        lines.append(f"{own:7.3f} {calls:8d} {per_call:8.1f}  {side:5}  {where}:{line}({name})")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.profile_run", description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1, help="timed runs (the first loads the kernels)")
    parser.add_argument("--profile", metavar="FILE", help="also run once under cProfile, written to FILE")
    parser.add_argument("--top", type=int, default=30, help="functions listed from the profile")
    parser.add_argument("--parts", action="store_true", help="also time the host's parts (PARTS)")
    parser.add_argument(
        "--first-tick", action="store_true", help="only: a fresh process's way to its first tick"
    )
    args = parser.parse_args()
    if args.first_tick:
        for i in range(args.repeat):
            wall, imports_s, said = first_tick()
            print(
                f"run {i + 1}: first tick {wall:.2f} s after spawn, {imports_s:.2f} s of it imports; {said}"
            )
        return 0
    for i in range(args.repeat):
        print(f"timed run {i + 1}:")
        for line in timed_run().lines():
            print("  " + line)
        if args.parts:
            for name, watch in parts_run().items():
                per_call = 1e6 * watch.seconds / max(watch.calls, 1)
                print(f"  {name:28} {watch.calls:6d} calls {per_call:7.1f} µs/call {watch.seconds:6.3f} s")
    if args.profile:
        print(profiled_run(args.profile, args.top))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
