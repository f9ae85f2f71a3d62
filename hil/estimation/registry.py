"""Estimators by name, chosen by configuration: the registry of :class:`~hil.estimation.interface.
EstimatorKind` s (after the transports' in :mod:`hil.link.transports`) and :class:`EstimatorChoice`, the
kind and settings a scenario's ``[estimator]`` table or ``--estimator NAME`` picks.

=================  ==================================================================================
name               estimator
=================  ==================================================================================
``variational``    the paper's variational estimator with its pre-filter and measurement handling
                   (:class:`hil.estimation.filter.AttitudeFilter`); setting ``preset``: ``"paper"``
                   (the default for a scenario) or ``"tuned"``. The default.
``vqf``            VQF (Laidig & Seel 2023) through the ``vqf`` package (``pip install vqf``):
                   :mod:`hil.estimation.vqf_adapter`; settings ``tau_acc_s``, ``tau_mag_s``,
                   ``motion_bias``, ``rest_bias``, ``mag_rejection``.
=================  ==================================================================================

Each name maps to ``"module:attribute"``, imported on first use, so an optional estimator's package is
only needed when it is chosen. Other packages add estimators as entry points in the group
``vscmg_hil.estimators`` whose name is the estimator's and whose value is ``"module:attribute"``, the
attribute an :class:`~hil.estimation.interface.EstimatorKind`. In a ``pyproject.toml``::

    [project.entry-points."vscmg_hil.estimators"]
    mine = "mypackage.estimator:MY_ESTIMATOR"

:func:`register_estimator` adds one at run time.

Every estimator but ``hil``'s variational one is built wrapped in a
:class:`~hil.estimation.checked.CheckedEstimator`: what a user's estimator returns is checked each step (a
finite rotation at the step's time, its rates within a gyroscope's bound; a batch of the steps' length),
and what it raises — in ``check``, ``build``, ``describe`` or mid-run, a ``sys.exit()`` too — is a
:class:`~hil.plugins.PluginError` (a ConfigError from ``check``, as is a check that returns no mapping of
settings) naming it, so a run that it failed ends as an error with its board disarmed. Pure
configuration, no I/O."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from hil.estimation.interface import Estimator, EstimatorKind, Site
from hil.plugins import PluginError, Registry, call_plugin, describe_value
from protocol.errors import ConfigError, HilError

ENTRY_POINT_GROUP = "vscmg_hil.estimators"
DEFAULT_ESTIMATOR = "variational"

# name -> "module:attribute", the attribute an EstimatorKind
_REGISTRY = Registry(
    ENTRY_POINT_GROUP,
    {
        "variational": "hil.estimation.variational_kind:VARIATIONAL",
        "vqf": "hil.estimation.vqf_adapter:VQF_ESTIMATOR",
    },
)
# the estimators whose outputs are not checked each step: hil's own variational one (its kernel flags and
# counts its own failures; it is the host's hot path)
_UNCHECKED = frozenset({"hil.estimation.variational_kind:VARIATIONAL"})


def register_estimator(name: str, target: str) -> None:
    """Add (or replace) the estimator called ``name``; ``target`` is ``"module:attribute"``, the attribute
    an :class:`~hil.estimation.interface.EstimatorKind`."""
    _REGISTRY.register(name, target)


def estimator_names() -> list[str]:
    """Every estimator's name, registered or installed."""
    return _REGISTRY.names()


def estimator_kind(name: str, where: str = "estimator") -> EstimatorKind:
    """The estimator kind called ``name``; ConfigError naming ``where`` for an unknown name or one whose
    module cannot be imported."""
    target = _REGISTRY.target(name)
    if target is None:
        raise ConfigError(f"unknown estimator {name!r} (known: {_REGISTRY.known()})", where)
    try:
        kind: EstimatorKind = _REGISTRY.load(target)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"estimator {name!r} ({target}) is not available: {exc}", where) from exc
    try:  # its attributes are the plugin's: a property that raises is its fault, said as a ConfigError
        what = call_plugin(f"estimator {name!r}", "reading its kind", lambda: _not_a_kind(kind))
    except PluginError as exc:
        raise ConfigError(f"estimator {name!r} ({target}) is not available: {exc.detail}", where) from exc
    if what is not None:
        raise ConfigError(f"estimator {name!r} ({target}) is not an EstimatorKind ({what})", where)
    return kind


def _not_a_kind(kind: Any) -> str | None:
    """Why ``kind`` is not an :class:`~hil.estimation.interface.EstimatorKind` in a few words, or None."""
    missing = [a for a in ("keys", "check", "build", "describe") if not hasattr(kind, a)]
    if missing:
        return f"no {', '.join(missing)}"
    if not isinstance(kind.keys, (set, frozenset)):
        return f"its keys are a {type(kind.keys).__name__}, not a set"
    return None


@dataclass(frozen=True)
class EstimatorChoice:
    """An estimator chosen by configuration: the kind's ``name`` and its ``settings``, checked and
    completed with the kind's defaults on construction (ConfigError naming ``where``: a scenario's file
    and key, or a command-line option). :meth:`build` makes a fresh estimator for a site — the host makes
    one at the start and after every restart of the phone's stream."""

    name: str = DEFAULT_ESTIMATOR
    settings: Mapping[str, Any] = field(default_factory=dict)
    where: str = field(default="estimator", compare=False, repr=False)

    def __post_init__(self) -> None:
        kind = estimator_kind(self.name, f"{self.where}.kind")
        unknown = set(self.settings) - kind.keys
        if unknown:
            key = sorted(unknown)[0]
            known = ", ".join(sorted(kind.keys | {"kind"}))
            raise ConfigError(
                f"unknown key for estimator {self.name!r}; known: {known}", f"{self.where}.{key}"
            )
        plugin = f"estimator {self.name!r}"
        try:
            checked = call_plugin(
                plugin, "its check", lambda: kind.check(self.settings, self.where), ConfigError
            )
            if not isinstance(checked, Mapping):
                raise PluginError(plugin, f"its check returned {describe_value(checked)}, not the settings")
            settings = call_plugin(plugin, "its check's settings, read,", lambda: dict(checked))
        except PluginError as exc:  # the kind's own fault: still a configuration the run cannot take
            raise ConfigError(str(exc), self.where) from exc
        object.__setattr__(self, "name", self.name.lower())
        object.__setattr__(self, "settings", settings)

    @property
    def kind(self) -> EstimatorKind:
        return estimator_kind(self.name, f"{self.where}.kind")

    def build(self, site: Site) -> Estimator:
        """A fresh estimator for ``site``: a user's wrapped in a
        :class:`~hil.estimation.checked.CheckedEstimator` (see the module docstring)."""
        from hil.estimation.checked import CheckedEstimator

        kind = self.kind
        if _REGISTRY.target(self.name) in _UNCHECKED:
            return kind.build(self.settings, site)
        plugin = f"estimator {self.name!r}"
        # the project's own (a ConfigError naming a key) passes as raised
        built = call_plugin(plugin, "build", lambda: kind.build(self.settings, site), HilError)
        if built is None or not callable(getattr(built, "step", None)):
            raise PluginError(plugin, f"build returned {type(built).__name__}, not an Estimator")
        return CheckedEstimator(built, self.name, site.sample_period_s)

    def describe(self) -> str:
        """One line: the estimator and its settings."""
        kind = self.kind
        return call_plugin(f"estimator {self.name!r}", "describe", lambda: str(kind.describe(self.settings)))

    @classmethod
    def by_name(cls, name: str, where: str) -> EstimatorChoice:
        """The estimator called ``name`` with its default settings (a command line's ``--estimator``:
        errors name the option ``where`` itself, not a table's key)."""
        estimator_kind(name, where)
        return cls(name, {}, where)

    def named(self, name: str | None, where: str) -> EstimatorChoice:
        """This choice with another estimator (``--estimator NAME``, checked naming ``where``): the same
        one unchanged, another with its default settings; None keeps this one."""
        if name is None or name.lower() == self.name:
            return self
        return EstimatorChoice.by_name(name, where)
