"""A run observer for tests to build on (:class:`hil.runtime.observer.RunObserver`)."""

from __future__ import annotations

from typing import Any


class SilentObserver:
    """A run's observer (:class:`hil.runtime.observer.RunObserver`) that does nothing: a test's observer
    derives from it and writes only the call it acts on."""

    def started(self, start: Any) -> None:
        """Nothing to do."""

    def row(self, row: Any) -> None:
        """Nothing to do."""

    def event(self, record: Any) -> None:
        """Nothing to do."""

    def tick(self, t: float) -> None:
        """Nothing to do."""

    def finished(self, summary: Any) -> None:
        """Nothing to do."""
