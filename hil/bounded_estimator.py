"""A user's estimator made to run its calls on a thread of its own, each waited for its bound — for the
layers that call an estimator on a user's clock (a run's host, its warm-up, a replay): the estimation
package itself starts no thread and reads no clock, so the worker is installed from above it."""

from __future__ import annotations

from hil.estimation.checked import CheckedEstimator
from hil.estimation.interface import Estimator
from hil.plugin_worker import PluginWorker


def with_bounded_calls(estimator: Estimator) -> Estimator:
    """``estimator``, a user's (:class:`~hil.estimation.checked.CheckedEstimator`) made to run its calls —
    each live step, a replay's batch ``run`` — on a thread of its own, each waited for its bound
    (:class:`~hil.plugin_worker.PluginWorker`): a call that never returned hung the run, or the replay,
    until it was killed. hil's own estimator is called directly."""
    if isinstance(estimator, CheckedEstimator):
        estimator.run_calls_with(PluginWorker(estimator.plugin).call)
    return estimator
