"""Where users extend ``hil``: a registry of names (URL schemes, estimator names) to ``"module:attribute"``
targets, imported on first use — ``hil``'s own in a table, another package's as entry points of the
registry's group. The board's transports (:mod:`hil.link.transports`), the phone sources
(:mod:`hil.link.sources`) and the estimators (:mod:`hil.estimation.registry`) are each one of these; each
says in its own words what is unknown or unavailable (its own error type, naming its option).
"""

from __future__ import annotations

import importlib
from typing import Any

from protocol.errors import HilError


class PluginError(HilError, RuntimeError):
    """A user's plugin (an estimator, a transport, a phone source) that raised its own exception or
    returned what its interface does not allow, mid-run: ``plugin`` names it (``"estimator 'mine'"``),
    ``detail`` says what it did and when. The run ends on it, as an error, its board disarmed."""

    def __init__(self, plugin: str, detail: str) -> None:
        super().__init__(f"{plugin}: {detail}")
        self.plugin = plugin
        self.detail = detail


class Registry:
    """Names → ``"module:attribute"``: ``builtin`` first, then the entry points of ``group`` (read once,
    on first use; a built-in name or one :meth:`register` set wins), names compared in lower case."""

    def __init__(self, group: str, builtin: dict[str, str]) -> None:
        self.group = group
        self._targets = {name.lower(): target for name, target in builtin.items()}
        self._discovered = False

    def _discover(self) -> None:
        if self._discovered:
            return
        self._discovered = True
        import importlib.metadata  # only here: reading the entry points costs a run that needs none 10+ ms

        for entry in importlib.metadata.entry_points(group=self.group):
            self._targets.setdefault(entry.name.lower(), entry.value)

    def register(self, name: str, target: str) -> None:
        """Add (or replace) ``name``; ``target`` is ``"module:attribute"``."""
        self._targets[name.lower()] = target

    def names(self) -> list[str]:
        """Every name, built in, installed or registered, sorted."""
        self._discover()
        return sorted(self._targets)

    def target(self, name: str) -> str | None:
        """The ``"module:attribute"`` of ``name``, or None when nobody registered it. A name built in or
        registered is answered without reading the entry points: they never replace it."""
        target = self._targets.get(name.lower())
        if target is not None:
            return target
        self._discover()
        return self._targets.get(name.lower())

    @staticmethod
    def load(target: str) -> Any:
        """The attribute ``target`` names, its module imported; ImportError or AttributeError as raised
        (the caller words them)."""
        module_name, _, attr = target.partition(":")
        return getattr(importlib.import_module(module_name), attr)
