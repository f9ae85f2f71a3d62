"""What Dask logs at a campaign's interruption that the campaign says better itself: two filters on Dask's
loggers, each installed once, that turn a traceback about a known, harmless consequence of Ctrl-C into one
line (or a debug record), while any other exception on the same logger keeps its traceback.

* :func:`quiet_scheduler_loss` — in a LocalCluster worker (its preload): the scheduler out of reach once
  the driver closes the campaign.
* :func:`quiet_interrupted_sync` — in the driver: distributed's own clean-up of a blocking call that
  Ctrl-C interrupted before the call had begun.
"""

from __future__ import annotations

import logging
from types import TracebackType

logger = logging.getLogger(__name__)


class _SchedulerLossUntraced(logging.Filter):
    """A LocalCluster worker's record of the scheduler out of reach (an ``OSError``: its connection closed)
    without the traceback: the scheduler lives in the driver, so it is gone only when the campaign closes
    (Ctrl-C twice put a worker's heartbeat traceback on the user's terminal after "interrupted"). The line
    itself is kept; any other exception keeps its traceback."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info and isinstance(record.exc_info[1], OSError):
            record.msg = f"{record.getMessage()} ({record.exc_info[1]!r})"
            record.args = None
            record.exc_info = None
            record.exc_text = None
        return True


def quiet_scheduler_loss() -> None:
    """Install :class:`_SchedulerLossUntraced` on the worker's ``distributed.worker`` logger (once)."""
    _install(logging.getLogger("distributed.worker"), _SchedulerLossUntraced)


def _last_frame(tb: TracebackType | None) -> TracebackType | None:
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb


class _InterruptedSyncUntraced(logging.Filter):
    """Drops tornado's "Exception in callback" record of one failure inside distributed, logging a debug
    line instead: a blocking client call (``distributed.utils.sync``: a future's result, a cancel) that a
    Ctrl-C interrupts schedules a callback that cancels the call's asyncio future, and when the interrupt
    came before the event loop had started the call, that future is not yet bound and the callback fails
    with a ``NameError`` on ``future`` (distributed 2026.8's ``sync`` no longer initialises it to ``None``).
    The interrupt itself is handled as any other (the campaign cancels its work and closes the cluster); the
    call goes on in the background, unneeded, until the cluster closes. Ctrl-C twice in ``hil montecarlo``
    put that traceback on the user's terminal beside "interrupted" (CI, 1 run in ~4). Any other exception
    in a callback keeps its record and traceback."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not record.exc_info or not isinstance(record.exc_info[1], NameError):
            return True
        last = _last_frame(record.exc_info[2])
        if last is None:
            return True
        code = last.tb_frame.f_code
        where = code.co_filename.replace("\\", "/")
        if code.co_name == "cancel" and where.endswith("distributed/utils.py"):
            logger.debug("an interrupted Dask call had not begun; its cancel failed: %s", record.exc_info[1])
            return False
        return True


def quiet_interrupted_sync() -> None:
    """Install :class:`_InterruptedSyncUntraced` on tornado's ``tornado.application`` logger (once), where
    the event loop's callbacks' exceptions are logged."""
    _install(logging.getLogger("tornado.application"), _InterruptedSyncUntraced)


def _install(log: logging.Logger, kind: type[logging.Filter]) -> None:
    if not any(isinstance(f, kind) for f in log.filters):
        log.addFilter(kind())
