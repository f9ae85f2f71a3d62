"""Monte Carlo campaigns on Dask: N dispersed lockstep runs of a scenario through the one closed loop (the
host, the emulated board and its protocol, the world: :func:`hil.runtime.run`), on a
``dask.distributed`` cluster — a LocalCluster on this machine (one single-threaded worker process per core)
or any running scheduler given by address. Both take the same path: :func:`run_campaign` gets a
:class:`distributed.Client` and never asks which kind it is.

The driver draws each run's parameters (:func:`~.dispersions.draw`: a pure function of seed and index),
skips the runs the output directory already holds, and submits chunks of ``batch`` runs, a few per worker
at a time (:data:`IN_FLIGHT_PER_WORKER`: nothing is held per run of the campaign before it starts); a
worker runs a chunk's runs one after another (:func:`stream_chunk`: a chunk amortises Dask's per-task
cost over its runs) and sends each run's result back as it finishes, as an event through the scheduler,
so the driver writes that run's row then and not when the chunk ends (:class:`~.store.ResultStore`):
Ctrl-C or a crash loses no finished run. The chunk's return value carries its results again: the driver
writes those it has not had yet, and a run written once is never written again (a chunk that Dask reruns
after losing its worker streams its first runs a second time).

The driver also listens to the scheduler's own events: a worker that leaves unexpectedly (its process
died) is reported as it happens (:class:`WorkerLoss`: which worker, when, the campaign's chunks it had,
whether Dask retried them) and counted in the report and summary.json. A chunk that Dask gave up on
(``KilledWorker``) is recorded as failed runs with the error, never dropped.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import itertools
import logging
import math
import os
import pickle
import queue
import signal
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil import version
from hil.cores import available_cores
from hil.files.bounded import load_json, read_document, regular_file_if_there
from hil.runtime.held_signals import STOP_SIGNALS, first_signal
from hil.runtime.held_signals import deferred as deferred_signals
from hil.runtime.runlog import SUMMARY, write_summary
from hil.scenario import Scenario
from protocol.errors import ConfigError, HilError, InputFormatError, LinkError

from .dask_logs import quiet_interrupted_sync, quiet_scheduler_loss
from .dispersions import Dispersions, RunParams, draw
from .metrics import trace_length
from .runner import CHECK_COLUMNS, RunResult, describe, run_one
from .store import (
    MANIFEST,
    MAX_RUNS,
    ResultStore,
    SessionRecord,
    checked_write,
    manifest,
    read_manifest,
    read_runs,
    read_session,
    session_ended,
)
from .summary import summarise

logger = logging.getLogger(__name__)

DEFAULT_BATCH = 4  # runs per Dask task: spreads Dask's per-task cost, keeps the workers balanced
MAX_BATCH = 10_000
"""The most runs one Dask task may run one after another."""
IN_FLIGHT_PER_WORKER = 4
"""Chunks submitted to Dask per worker thread at a time: enough to keep every worker busy (Dask queues a
few on each), few enough that a campaign of millions of runs holds only these in the driver and the
scheduler; the next chunk is submitted as one finishes."""
DEFAULT_TRACE_HZ = 5.0
WORKER_TTL_S = 15.0
"""How long a LocalCluster's scheduler waits for a worker's heartbeat (sent every 0.5 s, from a thread of
its own, whatever the worker runs) before its nanny restarts it and Dask reruns its chunks elsewhere. A
worker process stopped (SIGSTOP, a debugger, a frozen container) held its chunks, and the campaign, for
Dask's default of 5 minutes plus up to 5 more (the scheduler looks once per TTL); now 15 to 30 s. Dask
never waits less than 10 heartbeats (5 s). A scheduler of your own keeps its own setting
(``distributed.scheduler.worker-ttl``)."""
NO_WORKERS_S = 60.0
"""How long a session waits, in seconds, while the cluster has no worker at all and chunks are left, before
it ends on a :class:`LinkError` naming the scheduler (its runs left to the next session). A scheduler of
your own whose workers all died (SIGKILL, their machine gone), or whose workers cannot load the campaign's
task (an environment without vscmg-hil: the worker's stream breaks on the task's unpickling and the worker
closes), held the command for ever, the progress bar standing still. Time enough for a nanny's restart
(a second or two) or a worker started by hand. Dask's own setting for it, in this process's
configuration, is taken instead when it is set: ``distributed.scheduler.no-workers-timeout``
(``DASK_DISTRIBUTED__SCHEDULER__NO_WORKERS_TIMEOUT=5m``)."""
SCHEDULER_SILENCE_KEY = "distributed.comm.timeouts.connect"
"""Dask's setting (default 30 s) for how long a scheduler may leave the driver without an answer before
the session ends on a :class:`LinkError` naming it ("not answering for N s"). A scheduler that stops
answering without closing its connection — its process stopped (SIGSTOP), its machine frozen, a network
that drops every packet — held the campaign for ever: Dask's client waits on an open connection without a
bound, and the progress bar stood still. Long beside a busy scheduler's pause (a garbage collection of a
few seconds), which ends nothing. ``DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=10s`` sets it."""
PROBE_EVERY_S = 5.0
"""How often, in seconds, the driver asks the scheduler who it is (a small request answered at once by any
scheduler that runs), to learn it has gone silent: at most half :data:`SCHEDULER_SILENCE_KEY`'s time."""
CLOSE_S = 5.0
"""How long, in seconds, closing the client of a scheduler of your own is waited for. A healthy close takes
well under a second; a silent scheduler's waits while what the client still has to send fills the
connection (29 s measured, a task's 50 MB argument unsent), and Dask's own bound, twice the connection
timeout, ended in its TimeoutError's traceback in place of the error that ended the session. After this
the client is abandoned: its event loop's thread is a daemon; the scheduler sees the connection close as
the process ends."""
RESULTS_TOPIC = "hil-montecarlo-results"
"""The scheduler event topic the workers send each finished run on. One topic for every campaign (a
session's events carry its token): the scheduler keeps the last ``distributed.admin.low-level-log-length``
events of each topic for good, so a topic per session would leave that much behind on a long-lived
scheduler for every campaign it ever ran."""


@dataclass(frozen=True)
class Campaign:
    """What to run: ``runs`` runs (indices 0..runs-1) of ``scenario`` (its slew's ``duration_s`` is each
    run's length) under ``dispersions``, from ``seed``; ``batch`` runs per Dask task (run one after another);
    ``trace_hz`` the rate of the stored error traces."""

    scenario: Scenario
    dispersions: Dispersions
    runs: int
    seed: int
    batch: int = DEFAULT_BATCH
    trace_hz: float = DEFAULT_TRACE_HZ

    def __post_init__(self) -> None:
        for name, most in (("runs", MAX_RUNS), ("batch", MAX_BATCH)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= most:
                raise ConfigError(f"must be an integer in 1..{most}, got {value!r}", f"campaign.{name}")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"must be a non-negative integer, got {self.seed!r}", "campaign.seed")
        rate = self.scenario.loop.control_rate_hz
        if not (math.isfinite(self.trace_hz) and 0 < self.trace_hz <= rate):
            raise ConfigError(f"must be in (0, {rate:g}] Hz (the control rate)", "campaign.trace_hz")
        duration = self.scenario.slew.duration_s
        if trace_length(duration, self.trace_hz) < 1:  # 1e-300 Hz: traces of nothing
            raise ConfigError(
                f"{self.trace_hz:g} Hz samples no run's trace once in its {duration:g} s", "campaign.trace_hz"
            )
        if self.dispersions.scenario is not self.scenario:
            raise ConfigError("the dispersions are bound to another scenario", "campaign.dispersions")

    def draw(self, index: int) -> RunParams:
        return draw(self.dispersions, self.seed, index)

    def manifest(self) -> dict[str, Any]:
        sc = self.scenario
        checks = CHECK_COLUMNS if self.dispersions.faults is not None else ()
        return manifest(
            sc.name,
            sc.source,
            self.dispersions.text,
            self.seed,
            sc.slew.duration_s,
            self.trace_hz,
            trace_length(sc.slew.duration_s, self.trace_hz),
            self.dispersions.columns(),
            checks,
            board=str(sc.board_options.get("board", "emulator")),
        )


@dataclass(frozen=True)
class WorkerLoss:
    """A worker that left the cluster unexpectedly during the campaign (its process died or its machine or
    network went; a worker retired on purpose hands its tasks over and is no loss): ``worker`` its address,
    ``at`` when the driver heard of it (``time.time()``) and ``at_s`` how far into the session; ``tasks``
    this campaign's chunks it was running, holding queued or holding unread results of, ``runs`` the runs
    of those chunks. Dask reruns such a chunk on another worker (``retried``) until it has lost
    ``distributed.scheduler.allowed-failures`` workers (3; judged by this process's Dask configuration),
    then gives up (``given_up``): those runs are recorded as failed with ``KilledWorker``."""

    worker: str
    at: float
    at_s: float
    tasks: int
    runs: int
    retried: int
    given_up: int

    def describe(self) -> str:
        """One line for the console: the loss, as it happens."""
        clock = time.strftime("%H:%M:%S", time.localtime(self.at))
        head = f"worker {self.worker} lost at {clock} ({self.at_s:.1f} s in)"
        if not self.tasks:
            return f"{head}, running none of this campaign's chunks"
        line = f"{head} with {_count(self.tasks, 'chunk')} ({_count(self.runs, 'run')}) of this campaign"
        if self.retried:
            # on a worker it has, or the next that joins (none for NO_WORKERS_S: the session ends)
            line += f"; Dask reruns {_count(self.retried, 'chunk')} on a worker of the cluster"
        if self.given_up:
            line += (
                f"; Dask gave up on {_count(self.given_up, 'chunk')} (KilledWorker: lost too many workers), "
                "its runs are recorded as failed"
            )
        return line


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


@dataclass
class CampaignReport:
    """How a session went: ``skipped`` runs were already in the directory, ``completed`` finished now (of
    them ``failed`` with an error) in ``wall_s`` on ``workers`` worker threads; ``losses`` the workers lost
    meanwhile and ``workers_joined`` the workers that joined the cluster meanwhile (a nanny's restart of a
    lost one, or a new one); ``summary`` covers every run in the directory."""

    out_dir: Path
    runs: int
    skipped: int
    completed: int
    failed: int
    wall_s: float
    workers: int
    losses: list[WorkerLoss] = field(default_factory=list)
    workers_joined: int = 0
    summary: dict[str, Any] = field(default_factory=dict)
    plots: dict[str, Path] = field(default_factory=dict)

    @property
    def runs_per_minute(self) -> float:
        return 60.0 * self.completed / self.wall_s if self.wall_s > 0 else math.nan

    @property
    def workers_lost(self) -> int:
        return len(self.losses)


@contextmanager
def open_client(
    scheduler: str | None = None,
    workers: int | None = None,
    processes: bool = True,
    timeout_s: float = 10.0,
    worker_ttl_s: float = WORKER_TTL_S,
) -> Iterator[Any]:
    """A :class:`distributed.Client`: on the running scheduler at ``scheduler`` (``tcp://host:8786``), or
    on a LocalCluster of ``workers`` single-threaded workers (default: one per core), as processes (or
    threads of this process with ``processes=False``: for tests and debugging), whose scheduler restarts a
    worker silent for ``worker_ttl_s`` (:data:`WORKER_TTL_S`). Closed on exit."""
    from distributed import Client, LocalCluster

    quiet_interrupted_sync()
    if scheduler is not None:
        if workers is not None:
            raise ConfigError("--workers is for a local cluster; a scheduler has its own workers", "workers")
        check_address(scheduler)
        try:
            if not scheduler.startswith("inproc://"):  # a scheduler in this process: nothing to probe
                probe_scheduler(scheduler, timeout_s)
            client = Client(scheduler, timeout=timeout_s)
        except LinkError:
            raise
        except (OSError, TimeoutError) as exc:
            raise LinkError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from exc
        except Exception as exc:  # something answered, not as a scheduler (numpy asked for 3 EiB)
            raise LinkError(
                f"no Dask scheduler at {scheduler}: what answered there did not speak Dask's protocol "
                f"({describe(exc)})"
            ) from exc
        try:
            yield client
        finally:
            with deferred_signals():  # see below: a second Ctrl-C waits for the close
                _close_bounded(client, scheduler)
        return
    n = workers if workers is not None else available_cores()
    if n < 1:
        raise ConfigError(f"must be at least 1, got {n}", "workers")
    stack = ExitStack()
    try:
        with deferred_signals():  # a cluster interrupted half-started left a traceback at exit
            cluster = stack.enter_context(
                LocalCluster(
                    n_workers=n,
                    threads_per_worker=1,
                    processes=processes,
                    dashboard_address="127.0.0.1:0",
                    silence_logs=logging.ERROR,
                    preload=[__name__] if processes else [],  # dask_setup below: Ctrl-C is the driver's
                    scheduler_kwargs={"worker_ttl": worker_ttl_s},
                )
            )
            client = stack.enter_context(Client(cluster))
    except BaseException as exc:  # interrupted, or a worker killed as it started ("Nanny failed to start")
        with deferred_signals():
            stack.close()
        if not isinstance(exc, Exception):
            raise
        raise LinkError(f"a local Dask cluster of {n} workers could not start: {describe(exc)}") from exc
    try:
        yield client
    finally:
        # Ctrl-C pressed twice: the second came while the first's close was under way (well under a
        # second), threw it away half done, and Dask's exit hook then took 10 s more to close the
        # half-closed cluster after the command had said it was interrupted. Held until it is closed.
        with deferred_signals():
            stack.close()


def _close_bounded(client: Any, scheduler: str) -> None:
    """Close ``client`` within :data:`CLOSE_S`; a close that does not end by then (the scheduler silent:
    stopped, frozen, cut off) is logged and the client abandoned, so that what ended the session — the
    scheduler's silence said by :class:`_Driver` — is what the user is told, and when it happens."""
    try:
        client.close(timeout=CLOSE_S)
    except (TimeoutError, OSError) as exc:
        logger.warning("%s: the client's close not answered within %g s, left (%s)", scheduler, CLOSE_S, exc)


def check_address(scheduler: str) -> None:
    """Refuse a scheduler address that names no scheduler to connect to (a :class:`ConfigError` at
    ``scheduler``): not ``SCHEME://HOST:PORT``, a port beyond 1..65535, or ``tls://`` without Dask's TLS
    configuration (Dask's own TypeError otherwise)."""
    import dask
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(scheduler, strict=True)
        port = parse_host_port(location)[1] if scheme in ("tcp", "tls") else 1
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"not a scheduler address like tcp://HOST:8786 ({exc})", "scheduler") from None
    if not 0 < int(port) < 65536:
        raise ConfigError(f"port {port} is not in 1..65535", "scheduler")
    if scheme == "tls" and not dask.config.get("distributed.comm.tls.ca-file", None):
        raise ConfigError(
            "tls:// needs Dask's TLS configuration (distributed.comm.tls: ca-file and the client's cert and "
            "key; docs/montecarlo.md)",
            "scheduler",
        )


def probe_scheduler(scheduler: str, timeout_s: float) -> None:
    """Connect to ``scheduler`` within ``timeout_s`` and have Dask's handshake answered within ``timeout_s``
    more, then hang up. Dask's own ``Client(address, timeout=...)`` bounds the connection but not the
    handshake's answer: a port that accepts and never speaks (a proxy, a firewall, any other server that
    waits for its client) held the command for ever. A silent peer is a :class:`LinkError` naming the
    address. The two bounds are one after the other, not one for both: Dask's connect retries a refused
    port until ``timeout_s`` (its OSError: "cannot reach", from :func:`open_client`), and a bound of
    ``timeout_s`` on the whole raced it — a closed port (a scheduler not started yet, or gone) was said,
    one time in four, to have "accepted the connection and said nothing"."""
    import asyncio

    from distributed.comm import connect
    from distributed.security import Security

    args = Security().get_connection_args("client")

    async def handshake() -> None:
        comm = await asyncio.wait_for(connect(scheduler, timeout=timeout_s, **args), 2 * timeout_s)
        await comm.close()

    try:
        asyncio.run(handshake())
    except TimeoutError as exc:  # asyncio's is the built-in one since 3.11
        raise LinkError(
            f"no Dask scheduler at {scheduler}: no answer to Dask's handshake within {timeout_s:g} s "
            "(something accepted the connection and said nothing)"
        ) from exc


def dask_setup(worker: Any) -> None:
    """A LocalCluster worker process's preload: Ctrl-C in a terminal, and the terminal's SIGHUP when it
    closes, reach the whole process group; each worker printed its KeyboardInterrupt's traceback (or died
    of the hang-up under its work). The driver alone handles them (it cancels the work and closes the
    cluster, whose nannies stop the workers, by SIGTERM: that one stays the worker's)."""
    if threading.current_thread() is threading.main_thread():
        for signum in STOP_SIGNALS:
            if signum != signal.SIGTERM:
                signal.signal(signum, signal.SIG_IGN)
    quiet_scheduler_loss()


def chunks(indices: Iterable[int], count: int, batch: int, workers: int) -> Iterator[list[int]]:
    """The ``count`` ``indices`` in consecutive chunks of at most ``batch``, smaller when there are too few
    runs to keep every worker busy (then each worker gets about one chunk); made as they are taken, so
    nothing is held per run."""
    size = max(1, min(batch, math.ceil(count / max(workers, 1))))
    it = iter(indices)
    while chunk := list(itertools.islice(it, size)):
        yield chunk


def stream_chunk(
    scenario: Scenario,
    runs: Sequence[RunParams],
    trace_hz: float,
    session: str,
    code: dict[str, str | None] | None = None,
) -> list[RunResult]:
    """The Dask task: ``runs`` one after another (:func:`~.runner.run_one`, as :func:`~.runner.run_chunk`
    does), each result sent to the driver as soon as its run finishes, as an event on
    :data:`RESULTS_TOPIC` tagged with the driver's ``session`` token, so that its row reaches runs.csv then
    and not with the chunk's last run. Returns every result again: what the driver writes of a chunk whose
    events it has not had (they travel through the scheduler like everything else, but a client that
    reconnects misses them). ``code``: the driver's :func:`hil.version.describe`; a worker running other
    code refuses the chunk (a ConfigError naming both), so a campaign never mixes results of two versions."""
    from distributed import get_worker

    if code is not None and (why := version.mismatch(version.describe(), code)) is not None:
        raise ConfigError(f"this worker runs other code than the campaign's driver: {why}", "worker")

    try:
        worker = get_worker()
    except ValueError:  # called outside a Dask worker (a debugger): nothing to stream to
        worker = None
    results = []
    for run in runs:
        result = run_one(scenario, run, trace_hz)
        if worker is not None:  # events must be msgpack-able: the result travels pickled
            worker.log_event(RESULTS_TOPIC, {"session": session, "result": pickle.dumps(result)})
        results.append(result)
    return results


def run_campaign(
    campaign: Campaign,
    out_dir: str | os.PathLike[str],
    client: Any,
    on_result: Callable[[RunResult, int, int], None] | None = None,
    plots: bool = True,
    on_worker_lost: Callable[[WorkerLoss], None] | None = None,
) -> CampaignReport:
    """Run the campaign's missing runs on ``client`` into ``out_dir`` (created, or resumed: see the module
    docstring), then write ``summary.json`` and the plots. ``on_result(result, done, total)`` is called
    after each run is on disk (the CLI's progress bar), ``on_worker_lost(loss)`` when a worker is lost
    (default: a warning on this module's logger). For its duration the client is subscribed to the
    scheduler's ``all`` event topic (where workers' comings and goings are announced; a handler already
    there is replaced) and to :data:`RESULTS_TOPIC`. KeyboardInterrupt cancels the pending work and
    propagates; every run finished by then is on disk, and a summary.json an earlier session wrote is
    summarised again over them, marked interrupted (:func:`_summary_after_interrupt`).

    ``client`` None: no cluster, for a directory that holds every run already (:func:`runs_left` is 0):
    the runs are summarised again, on 0 workers; a run left to do is then a :class:`ConfigError`."""
    out = Path(out_dir)
    start = time.perf_counter()
    workers = 0 if client is None else max(1, sum(_cluster_threads(client).values()))
    # Everything the session writes is written under the directory's lock, its summary and plots too: they
    # were written after it was let go, and a second session that took the directory meanwhile appended
    # runs that summary never counted (and, killed, left it standing beside a longer runs.csv)
    with ResultStore(out, campaign.manifest()) as store:
        skipped = sum(1 for i in store.finished if 0 <= i < campaign.runs)
        if client is None and skipped < campaign.runs:
            raise ConfigError(
                f"{campaign.runs - skipped} of the campaign's {campaign.runs} runs are not in the "
                "directory yet: they need a cluster",
                str(out),
            )
        todo = (i for i in range(campaign.runs) if i not in store.finished)
        driver = _Driver(campaign, store, client, start, skipped, on_result, on_worker_lost)
        store.record_session(campaign.runs, "running")
        try:
            if client is not None:
                driver.run(chunks(todo, campaign.runs - skipped, campaign.batch, workers), workers)
        except KeyboardInterrupt as exc:
            _summary_after_interrupt(out, campaign, _record_session_end(store, campaign.runs, exc))
            raise
        except HilError as exc:
            # the scheduler lost, a worker running other code, a full disk: the summary said so
            ended = _record_session_end(store, campaign.runs, exc)
            try:
                _summary_after_interrupt(out, campaign, ended)
            except HilError as err:  # what ended the session is what is raised
                logger.warning("%s: not summarised again after %s: %s", out, describe(exc), err)
            raise
        except BaseException as exc:
            _record_session_end(store, campaign.runs, exc)
            raise
        ended = _record_session_end(store, campaign.runs, None)
        report = CampaignReport(
            out,
            campaign.runs,
            skipped,
            driver.completed,
            driver.failed,
            time.perf_counter() - start,
            workers,
            driver.losses,
            driver.joined,
        )
        report.summary = summarise_dir(
            out, campaign.scenario, workers_lost=report.workers_lost, locked_here=True, ended=ended
        )
        if plots:
            from .plots import plot_campaign

            sc = campaign.scenario
            report.plots = plot_campaign(out, sc.settle_deg, sc.spacecraft.limits.max_gimbal_rate)
    return report


def _record_session_end(store: ResultStore, runs_asked: int, exc: BaseException | None) -> str:
    """Record in campaign.json how the session ended: ``finished`` (``exc`` None: every run it asked for
    is on disk), ``interrupted`` by the signal (Ctrl-C, SIGTERM), or ``stopped`` by the error ``exc``.
    Held from a second signal while it is written. A write the disk refuses is logged, not raised: what
    ended the session is what is raised, and a finished session's summary.json is written (or refused,
    naming it) all the same; the record still says ``running`` (read back: ``killed``). Returns how the
    session ended in :func:`~.store.session_ended`'s words: what its own summary says, whether or not the
    disk took the record (read from a record the disk refused, a finished session's summary said
    ``killed``)."""
    if exc is None:
        state, detail = "finished", {}
    elif isinstance(exc, KeyboardInterrupt):
        state, detail = "interrupted", {"signal": first_signal(exc).name}
    else:
        state, detail = "stopped", {"error": describe(exc)}
    try:
        with deferred_signals():
            store.record_session(runs_asked, state, **detail)
    except HilError as err:
        # said with what it leaves: a record of ``running`` that no session holds, which every reader of
        # the directory (``hil report``) takes for a session killed, unless this session's summary.json
        # (written next) says it finished over the same runs
        logger.warning(
            "%s: the session's end not recorded: %s (it still says running: read back without this "
            "session's summary.json, the session is said killed)",
            store.dir / MANIFEST,
            err,
        )
    return session_ended(state, detail)


def runs_left(campaign: Campaign, out_dir: str | os.PathLike[str]) -> int:
    """How many of ``campaign``'s runs ``out_dir`` does not hold yet, read as :func:`run_campaign` reads
    it (the directory made, or checked against the campaign and its torn tail repaired): 0 says a session
    has nothing to run, so no cluster need be started or reached (re-running a finished campaign for its
    summary once started a LocalCluster, or failed on a scheduler since gone). A directory without a
    campaign's manifest (none yet) has every run left, and is neither made nor touched here: a campaign
    that never starts (its scheduler out of reach) creates nothing."""
    if not os.path.lexists(Path(out_dir) / MANIFEST):
        return campaign.runs
    with ResultStore(out_dir, campaign.manifest()) as store:
        return campaign.runs - sum(1 for i in store.finished if 0 <= i < campaign.runs)


def _its_runs_killed_workers(exc: BaseException) -> bool:
    """Whether a chunk's error is Dask giving up on it after it lost a worker each time it ran it
    (``KilledWorker``: its runs kill their process) — the runs' own failure — rather than a reason outside
    them."""
    from distributed.scheduler import KilledWorker

    return isinstance(exc, KilledWorker)


def _no_workers_s() -> float:
    """:data:`NO_WORKERS_S`, or Dask's ``distributed.scheduler.no-workers-timeout`` where this process's
    configuration sets it (a duration: ``"90s"``, ``"5 minutes"``, seconds as a number); one that is not a
    positive duration is a :class:`ConfigError` naming the setting."""
    return _dask_seconds("distributed.scheduler.no-workers-timeout", NO_WORKERS_S)


def _scheduler_silence_s() -> float:
    """How long a silent scheduler is waited for, in seconds: Dask's :data:`SCHEDULER_SILENCE_KEY` (30 s
    unless this process's configuration says otherwise); a ConfigError naming it if it is no positive
    duration."""
    return _dask_seconds(SCHEDULER_SILENCE_KEY, 30.0)


def _dask_seconds(key: str, default: float) -> float:
    """The duration Dask's configuration sets at ``key`` in seconds (``"90s"``, ``"5 minutes"``, seconds
    as a number), ``default`` where it sets none; one that is not a positive duration is a
    :class:`ConfigError` naming ``key``."""
    import dask
    from dask.utils import parse_timedelta

    value = dask.config.get(key, None)
    if value is None:
        return default
    try:
        seconds = float(parse_timedelta(value, default="seconds"))
    except (ValueError, TypeError, KeyError) as exc:
        raise ConfigError(f"not a duration like 60s: {value!r} ({exc})", key) from None
    if not (math.isfinite(seconds) and seconds > 0):
        raise ConfigError(f"must be a positive duration, got {value!r}", key)
    return seconds


def _scheduler_address(client: Any) -> str:
    """The address of ``client``'s scheduler, for the errors that name it."""
    return getattr(getattr(client, "scheduler", None), "address", None) or "the scheduler"


def _not_answering(client: Any, silence_s: float) -> str:
    """What an error says of a scheduler that has not answered ``client`` for ``silence_s``."""
    return (
        f"{_scheduler_address(client)}: not answering for {silence_s:g} s: the scheduler process stopped, "
        f"its machine frozen or the network between cut ({SCHEDULER_SILENCE_KEY} sets the wait)"
    )


def _cluster_threads(client: Any) -> dict[str, int]:
    """The cluster's worker threads by worker address, asked of the scheduler within
    :data:`SCHEDULER_SILENCE_KEY`'s time: the question has no bound of its own, and a scheduler stopped
    as the session began held it for ever. A silent one is a :class:`LinkError` naming it."""
    silence_s = _scheduler_silence_s()
    try:
        return dict(client.nthreads(callback_timeout=silence_s))
    except TimeoutError as exc:
        raise LinkError(f"{_not_answering(client, silence_s)}; no run started") from exc


def _now() -> tuple[float, float]:
    """When an event arrived: the wall clock (to print) and ``perf_counter`` (the session's clock)."""
    return time.time(), time.perf_counter()


class _Driver:
    """One session's submission and bookkeeping. Everything that happens elsewhere — a run finished on a
    worker (an event on :data:`RESULTS_TOPIC`), a chunk finished (its future's callback), a worker came or
    went (the scheduler's ``all`` topic) — is put on one queue by the client's threads and handled here in
    order, on the caller's thread: the store and the callbacks are only ever touched from there, and a
    loss is reported the moment it arrives rather than with the next result."""

    _WAIT_S = 0.5  # the queue is polled, not waited on for ever: Ctrl-C is seen within this

    def __init__(
        self,
        campaign: Campaign,
        store: ResultStore,
        client: Any,
        start: float,
        skipped: int,
        on_result: Callable[[RunResult, int, int], None] | None,
        on_worker_lost: Callable[[WorkerLoss], None] | None,
    ) -> None:
        import dask

        self.campaign, self.store, self.client = campaign, store, client
        self.start, self.skipped = start, skipped
        self.on_result, self.on_worker_lost = on_result, on_worker_lost
        self.session = uuid.uuid4().hex
        self.events: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        # future key -> (the future, its runs) until the chunk is done and read: held, Dask keeps the result
        self.chunks: dict[Any, tuple[Any, list[RunParams]]] = {}
        self.lost_by: dict[Any, int] = {}  # future key -> workers it was on when they were lost
        self.allowed_failures = int(dask.config.get("distributed.scheduler.allowed-failures", 3))
        self.no_workers_s = _no_workers_s()
        # the cluster's workers by address, from the scheduler's news (a set: an announcement heard twice,
        # or a worker both listed and announced as it joined, is one worker), and since when (perf_counter)
        # it has had none, while it has none
        self.workers_here: set[str] = set()
        self.no_workers_since: float | None = None
        self.completed = self.failed = self.joined = 0
        self.losses: list[WorkerLoss] = []
        # the first chunk lost for a reason outside its runs: they and the rest are left to the next session
        self.outside_error: BaseException | None = None
        # the scheduler's silence (:meth:`_check_scheduler`): the question out to it, when (perf_counter) the
        # oldest question it has not answered was asked (None: it answered the last), when to ask next
        self.silence_s = _scheduler_silence_s()
        self.probe_every_s = min(PROBE_EVERY_S, self.silence_s / 2)
        self.probe: concurrent.futures.Future[Any] | None = None
        self.unanswered_since: float | None = None
        self.next_probe_at = time.perf_counter()

    def run(self, chunk_indices: Iterator[list[int]], workers: int) -> None:
        """Submit chunks, :data:`IN_FLIGHT_PER_WORKER` per worker at a time (another as each finishes),
        and handle the queue until every chunk is done."""
        client = self.client
        client.subscribe_topic(RESULTS_TOPIC, lambda event: self.events.put(("result", event[1])))
        client.subscribe_topic("all", lambda event: self.events.put(("cluster", (_now(), event[1]))))
        try:
            self._workers_now(set(_cluster_threads(client)))  # after subscribing: none joins unheard
            self._submit(chunk_indices, workers)
            while self.chunks:
                self._check_workers()
                self._check_scheduler()
                try:
                    kind, item = self.events.get(timeout=self._WAIT_S)
                except queue.Empty:
                    continue
                self._handle(kind, item, chunk_indices, workers)
            # What came while the last chunk was read is handled too: a worker lost holding that chunk's
            # result (stopped, then restarted by its nanny) held the read up until Dask had rerun it, and
            # its loss, queued meanwhile, was left unread: not reported, not counted in summary.json.
            while True:
                try:
                    kind, item = self.events.get_nowait()
                except queue.Empty:
                    break
                self._handle(kind, item, chunk_indices, workers)
        except BaseException:
            client.cancel([future for future, _ in self.chunks.values()])
            raise
        finally:
            if self.probe is not None:  # a question a silent scheduler never answers: not left waiting
                self.probe.cancel()
            with suppress(Exception):  # a scheduler gone: nothing to unsubscribe from
                client.unsubscribe_topic(RESULTS_TOPIC)
                client.unsubscribe_topic("all")
        if self.outside_error is not None:
            self._raise_outside_error()

    def _raise_outside_error(self) -> None:
        """End the session on a chunk lost for a reason outside its runs: a :class:`ConfigError` it raised
        (a worker running other code) as it is, anything else — the scheduler's connection lost — a
        :class:`LinkError` naming the scheduler; each saying how many runs were left for the next session
        (the same command again runs them)."""
        exc = self.outside_error
        assert exc is not None
        left = self._not_run()
        if isinstance(exc, ConfigError):
            raise ConfigError(f"{exc.detail} ({left})", exc.where) from exc
        address = _scheduler_address(self.client)
        raise LinkError(f"{address}: the campaign's work was lost: {describe(exc)} ({left})") from exc

    def _not_run(self) -> str:
        """What the errors that end a session say of the runs left to the next one."""
        not_run = self.campaign.runs - self.skipped - self.completed
        return f"{_count(not_run, 'run')} not run: the same command again runs them"

    def _check_scheduler(self) -> None:
        """Ask the scheduler who it is every :attr:`probe_every_s`, without waiting for the answer here
        (the question is one coroutine on the client's event loop), and end the session when a question
        has gone unanswered for :data:`SCHEDULER_SILENCE_KEY`'s time: a :class:`LinkError` naming the
        scheduler and the runs left (not recorded: the same command again runs them). Nothing else the
        driver waits on is bounded — its chunks' completions and results come when the scheduler says so —
        and a scheduler stopped without closing its connection (SIGSTOP, a frozen VM) held the campaign
        for ever. A question that fails (the connection refused while the client reconnects) is asked
        again, its clock running on; an answer, however late, stops it: a busy scheduler ends nothing."""
        now = time.perf_counter()
        probe = self.probe
        if probe is not None and probe.done():
            self.probe = None
            if not probe.cancelled() and probe.exception() is None:
                self.unanswered_since = None
        if self.unanswered_since is not None and now - self.unanswered_since >= self.silence_s:
            raise self._silent()
        if self.probe is None and now >= self.next_probe_at:
            scheduler = self.client.scheduler
            self.probe = asyncio.run_coroutine_threadsafe(scheduler.identity(), self.client.loop.asyncio_loop)
            self.next_probe_at = now + self.probe_every_s
            if self.unanswered_since is None:
                self.unanswered_since = now

    def _silent(self) -> LinkError:
        """The error that ends a session whose scheduler has not answered for :attr:`silence_s`."""
        return LinkError(f"{_not_answering(self.client, self.silence_s)}. {self._not_run()}")

    def _handle(self, kind: str, item: Any, chunk_indices: Iterator[list[int]], workers: int) -> None:
        """One event from the queue: a streamed result, a chunk done (and the next submitted), or the
        cluster's news."""
        if kind == "result":
            self._streamed(item)
        elif kind == "done":
            self._chunk_done(item)
            self._submit(chunk_indices, workers)
        else:
            self._cluster_event(*item)

    def _submit(self, chunk_indices: Iterator[list[int]], workers: int) -> None:
        """Submit chunks until :data:`IN_FLIGHT_PER_WORKER` per worker (those it started with, plus those
        that joined, less those lost) are in flight, or none is left — none after a chunk was lost for a
        reason outside its runs (:meth:`_chunk_done`)."""
        if self.outside_error is not None:
            return
        campaign = self.campaign
        window = IN_FLIGHT_PER_WORKER * max(1, workers + self.joined - len(self.losses))
        while len(self.chunks) < window:
            indices = next(chunk_indices, None)
            if indices is None:
                return
            runs = [campaign.draw(i) for i in indices]
            future = self.client.submit(
                stream_chunk,
                campaign.scenario,
                runs,
                campaign.trace_hz,
                self.session,
                version.describe(),
                pure=False,
            )
            self.chunks[future.key] = future, runs
            future.add_done_callback(lambda f: self.events.put(("done", f)))

    def _record(self, result: RunResult) -> None:
        """Write a run's row (its commit record) unless it is written already, then tell the caller."""
        if result.index in self.store.finished:
            return  # this session wrote it (streamed, then in its chunk's result; or a rerun chunk's)
        self.store.append(result)
        self.completed += 1
        self.failed += not result.ok
        if self.on_result is not None:
            self.on_result(result, self.skipped + self.completed, self.campaign.runs)

    def _streamed(self, message: Mapping[str, Any]) -> None:
        if message.get("session") == self.session:  # not another campaign's on the same scheduler
            self._record(pickle.loads(message["result"]))

    def _chunk_done(self, future: Any) -> None:
        if future.key not in self.chunks:
            return
        _, runs = self.chunks.pop(future.key)
        try:
            # its results come through the scheduler: one gone silent since it said the chunk was done
            # held this read for ever (a task's own TimeoutError is no concern: stream_chunk raises none)
            results = future.result(timeout=self.silence_s)
        except TimeoutError as exc:
            raise self._silent() from exc
        except Exception as exc:
            if not _its_runs_killed_workers(exc):
                # Lost for a reason outside its runs — the scheduler gone (the chunk cancelled), a worker
                # running other code that refused it: its runs are not recorded, so the next session runs
                # them. (They were recorded failed, "chunk lost", and a resume never ran them again.) No
                # more chunks go out; the session ends on the first such error (:meth:`run`).
                if self.outside_error is None:
                    self.outside_error = exc
                return
            # Dask gave up on the chunk: it lost a worker each time it ran it (a run that kills its
            # process): recorded failed, never dropped
            results = [RunResult.failed(r, f"chunk lost: {describe(exc)}") for r in runs]
        for result in results:
            self._record(result)
        self.store.sync()

    def _cluster_event(self, at: tuple[float, float], message: Mapping[str, Any]) -> None:
        action = message.get("action")
        if action == "add-worker":
            self.joined += 1
            self._workers_now(self.workers_here | {str(message.get("worker"))})
        elif action == "remove-worker":
            self._workers_now(self.workers_here - {str(message.get("worker"))})
            if not message.get("expected", False):
                self._lost(str(message.get("worker")), at, message)

    def _workers_now(self, workers: set[str]) -> None:
        """The cluster's workers are now ``workers``: the clock of a cluster without any starts as the
        last leaves (or at once, for a scheduler that has none), and stops as one joins."""
        self.workers_here = workers
        if workers:
            self.no_workers_since = None
        elif self.no_workers_since is None:
            self.no_workers_since = time.perf_counter()

    def _check_workers(self) -> None:
        """End the session on a cluster that has had no worker for :data:`NO_WORKERS_S` while chunks are
        left: a :class:`LinkError` naming the scheduler, the workers lost and the runs left (not recorded:
        the same command again runs them). The chunks still out are cancelled by :meth:`run`."""
        since = self.no_workers_since
        if since is None or time.perf_counter() - since < self.no_workers_s:
            return
        address = _scheduler_address(self.client)
        lost = f" (the last left {since - self.start:.1f} s in; {_count(len(self.losses), 'worker')} lost)"
        raise LinkError(
            f"{address}: no worker for {self.no_workers_s:g} s{lost if self.losses else ''}, nothing runs "
            "the campaign. A worker that cannot load its task (an environment without vscmg-hil, or "
            f"another Python) leaves at once: its log says why. {self._not_run()}"
        )

    def _lost(self, worker: str, at: tuple[float, float], message: Mapping[str, Any]) -> None:
        held = set(message.get("processing-tasks", ())) | set(message.get("lost-computed-tasks", ()))
        ours = [key for key in held if key in self.chunks]
        retried = given_up = 0
        for key in ours:
            self.lost_by[key] = self.lost_by.get(key, 0) + 1
            if self.lost_by[key] > self.allowed_failures:
                given_up += 1
            else:
                retried += 1
        runs = sum(len(self.chunks[key][1]) for key in ours)
        clock, monotonic = at
        loss = WorkerLoss(worker, clock, monotonic - self.start, len(ours), runs, retried, given_up)
        self.losses.append(loss)
        if self.on_worker_lost is not None:
            self.on_worker_lost(loss)
        else:
            logger.warning("%s", loss.describe())


def summarise_dir(
    out_dir: str | os.PathLike[str],
    scenario: Scenario,
    workers_lost: int | None = None,
    write: bool = True,
    locked_here: bool = False,
    ended: str | None = None,
) -> dict[str, Any]:
    """Summarise every run in ``out_dir`` against ``scenario``'s requirements and (``write``) write
    summary.json, with ``workers_lost``: the workers the session that wrote it lost. None, as `hil report`
    re-summarising a directory says, carries over what only a session knows from the existing summary.json:
    its ``workers_lost`` (0 without one) and its ``interrupted`` record (the runs asked for; its runs on
    disk counted again) — a report once rewrote the file without it, and the campaign no longer said it
    was interrupted. ``write=False`` (``hil report --no-plots``) leaves the directory as it is: a read-only
    campaign is still reported.

    The runs' duration, which ``settle`` is judged against, is the campaign's own (campaign.json's
    ``duration_s``, as its plots take it), not ``scenario``'s: the scenario `hil report` rebuilds from the
    TOML text campaign.json keeps says its file's ``duration_s``, not ``--duration``'s, and a campaign
    run with ``--duration 30`` on a scenario of 10 s was reported "settle_s <= 10: 0 %" — and its
    summary.json rewritten so — where `hil montecarlo` had printed 100 %. ``--duration`` is the one
    campaign option that moves a verdict's limit; ``settle_deg`` and the gimbal-rate limit are in the
    scenario text campaign.json keeps (``--board`` and ``--seed`` change neither).

    ``locked_here``: this process holds the directory's lock (the session itself, or ``hil report``
    through :func:`~.store.holding_dir`): its session record read so (:func:`~.store.read_session`).
    ``ended``: the session's own word for how it ended, over campaign.json's record of it."""
    sc = scenario
    info = read_manifest(out_dir)
    duration_s = float(info["duration_s"])
    # runs.csv's header held to campaign.json's columns: one edited by hand is an error naming it, never a
    # metric silently missing from every figure (or a KeyError's traceback where the plots read it)
    results = read_runs(out_dir, columns=info["columns"])
    summary = summarise(results, sc.name, duration_s, sc.settle_deg, sc.spacecraft.limits.max_gimbal_rate)
    # a duration too short for the slew to settle: its settle and final_error verdicts are the duration's
    # (a fault campaign's runs do not count such a miss against back_in_control: runner.run_faulted)
    shortfall = sc.time_to_judge().shortfall(duration_s)
    if shortfall is not None:
        summary["too_short_to_judge"] = shortfall
    interrupted = None
    previous: dict[str, Any] = {}
    if workers_lost is None:
        previous = _previous_summary(Path(out_dir) / SUMMARY)
        workers_lost = _workers_lost(previous)
        interrupted = previous.get("interrupted")
    summary["workers_lost"] = workers_lost
    session = read_session(out_dir, info, locked_here)
    if ended is not None:
        session = SessionRecord(session.runs_asked, ended)
    elif session.ended == "killed" and _finished_over(previous, session, summary):
        # its end record refused by the disk (campaign.json still says running), its summary.json not:
        # written under the lock, as the session's last act, over these very runs — the session finished
        session = SessionRecord(session.runs_asked, "finished")
    summary["runs_asked"], summary["ended"] = session.runs_asked, session.ended
    if session.runs_asked is not None:
        # whole when every run asked for (indices 0..N-1) is on disk and readable, however its session
        # ended after (``ended`` says it); the rows of an earlier, larger ask are in the figures too
        asked_on_disk = int((results.index < session.runs_asked).sum())
        if asked_on_disk < session.runs_asked:
            interrupted = {
                **(interrupted if isinstance(interrupted, dict) else {}),
                "runs_asked": session.runs_asked,
                "runs_asked_on_disk": asked_on_disk,
                "ended": session.ended,
            }
        else:
            interrupted = None  # an earlier session's record; this one finished every run
    if isinstance(interrupted, dict):
        summary["interrupted"] = {**interrupted, "runs_on_disk": summary.get("runs")}
    if write:
        # a full disk, or a directory where summary.json (or its temporary) should be, was an OSError's
        # traceback after every run had finished: an error naming the file (status 2), the runs on disk
        checked_write(Path(out_dir) / SUMMARY, lambda: write_summary(out_dir, summary))
    return summary


def _finished_over(previous: Mapping[str, Any], session: SessionRecord, summary: Mapping[str, Any]) -> bool:
    """Whether the summary.json ``previous`` is a finished session's over the runs ``summary`` counts now,
    that session asking ``session``'s runs: the word of a session whose campaign.json record the disk
    refused (a session writes its summary.json under the directory's lock, before it lets go)."""
    return (
        previous.get("ended") == "finished"
        and previous.get("runs_asked") == session.runs_asked
        and previous.get("runs") == summary.get("runs")
        and previous.get("ok") == summary.get("ok")
    )


def write_campaign_summary(out_dir: str | os.PathLike[str], summary: Mapping[str, Any]) -> None:
    """``summary`` as ``out_dir``'s summary.json (atomically); a refusal a ConfigError naming it."""
    checked_write(Path(out_dir) / SUMMARY, lambda: write_summary(out_dir, summary))


def _summary_after_interrupt(out: Path, campaign: Campaign, ended: str) -> None:
    """An interrupted session that extended a campaign (``--runs 8`` on one of 4, stopped after its 6th
    run) left the earlier session's summary.json saying 4 runs, 4 ok, beside a runs.csv of 6 — and nothing
    on disk said which was current. That summary is written again over the runs on disk, with
    ``interrupted``: the runs asked for, those on disk, how the session ended (campaign.json's session
    record: ``interrupted (SIGINT)``, ``stopped: ...`` — a session stopped by an error, its scheduler
    lost, is no less partial) and that the plots are the earlier session's (``hil report DIR``
    summarises and draws them anew). A campaign stopped before any summary was written is left without
    one, as before: its campaign.json says it (:data:`~.store.SESSION`). Called under the directory's
    lock, by the session that ``ended`` so."""
    path = out / SUMMARY
    if not path.is_file():
        return
    summary = summarise_dir(out, campaign.scenario, locked_here=True, ended=ended)
    summary["interrupted"] = {
        **summary.get("interrupted", {}),
        "runs_asked": campaign.runs,
        "runs_on_disk": summary.get("runs"),
        "plots": "not drawn for these runs: hil report DIR draws them",
    }
    checked_write(path, lambda: write_summary(out, summary))
    logger.warning("%s: summarised again over the runs on disk, marked interrupted", path)


def _previous_summary(path: Path) -> dict[str, Any]:
    """An existing summary.json's object; empty if there is none or it is damaged (not JSON, larger than
    or nested deeper than any document hil reads, not an object: said). Read through the bounded readers:
    ``[`` x 200000 was a RecursionError's traceback from ``hil report``. Its kind is checked before it is
    opened: a FIFO there (whose open waits for a writer) hung ``hil report`` for ever, and is refused as
    runs.csv's would be (a ConfigError naming it)."""
    regular_file_if_there(
        path, ConfigError, hint=" (a directory, a FIFO or a device): hil writes summary.json there; remove it"
    )
    try:
        doc = load_json(read_document(path, InputFormatError, SUMMARY), str(path))
    except InputFormatError as exc:
        if path.exists():
            logger.warning("%s: %s; its workers_lost taken as 0", path, exc.detail)
        return {}
    return doc if isinstance(doc, dict) else {}


def _workers_lost(previous: Mapping[str, Any]) -> int:
    """``workers_lost`` of an earlier summary; 0 if it does not say, or it is no non-negative integer."""
    value = previous.get("workers_lost", 0)
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else 0
