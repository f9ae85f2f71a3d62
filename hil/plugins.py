"""Where users extend ``hil``: a registry of names (URL schemes, estimator names) to ``"module:attribute"``
targets, imported on first use — ``hil``'s own in a table, another package's as entry points of the
registry's group. The board's transports (:mod:`hil.link.transports`), the phone sources
(:mod:`hil.link.sources`) and the estimators (:mod:`hil.estimation.registry`) are each one of these; each
says in its own words what is unknown or unavailable (its own error type, naming its option).
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable
from typing import Any, TypeVar

from protocol.errors import HilError, RunHung


class PluginError(HilError, RuntimeError):
    """A user's plugin (an estimator, a transport, a phone source) that raised its own exception or
    returned what its interface does not allow, mid-run: ``plugin`` names it (``"estimator 'mine'"``),
    ``detail`` says what it did and when. The run ends on it, as an error, its board disarmed."""

    def __init__(self, plugin: str, detail: str) -> None:
        super().__init__(f"{plugin}: {detail}")
        self.plugin = plugin
        self.detail = detail


class PluginTimeout(PluginError, TimeoutError):
    """A plugin's call that did not return within its bound (:class:`hil.plugin_worker.PluginWorker`): a
    step blocked on a lock, a socket or an ``Event`` that never comes. The run ends on it as on any
    :class:`PluginError`; the call's thread is left behind (see :class:`hil.plugin_worker.PluginWorker`)."""


T = TypeVar("T")

PASSES = (KeyboardInterrupt, GeneratorExit, RunHung)
"""What a plugin may raise that is never made its error: Ctrl-C (and SIGTERM through ``hil``'s CLI) is the
user's, a GeneratorExit Python's own, a :class:`~protocol.errors.RunHung` the campaign's (its run's wall
budget, raised wherever the run's thread is: a plugin's import it landed in was reported as the plugin's
failure). Everything else is caught — a ``SystemExit`` too: a library written
as a script calls ``sys.exit()`` on a failure of its own, which escaped every ``except Exception`` and ended
``hil`` with the plugin's status (0 for ``sys.exit()``), no word, the summary "error: " and, when a
transport's reader thread was the one to exit, the board's final Disarm unconfirmed."""

MAX_DEPTH = 32
"""How deeply what a plugin hands over for ``summary.json`` or ``events.jsonl`` may nest (dicts, lists): a
record's sections are a few levels deep; 100 000 levels made the JSON encoder raise RecursionError where
the run writes its ending, and a cycle never ends."""


def raised(exc: BaseException) -> str:
    """``exc`` in a few words: its type and message (its type alone when it has none, or one that raises)."""
    try:
        text = str(exc)
    except Exception:  # its __str__ is the plugin's too
        text = ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def call_plugin(
    plugin: str,
    what: str,
    call: Callable[[], T],
    passes: type[BaseException] | tuple[type[BaseException], ...] = PluginError,
) -> T:
    """``call()``, a call into ``plugin``: whatever it raises (its own exception, Python's, a SystemExit)
    becomes a :class:`PluginError` naming ``plugin`` and ``what`` (``"step at t = 3.2 s"``), ``from`` it.
    ``passes`` (the project's own errors the plugin's interface lets it raise, a PluginError of a nested
    check) and :data:`PASSES` go through as raised. The one place the wrappers
    (:mod:`hil.estimation.checked`, :mod:`hil.link.sources.checked`, :mod:`hil.link.transports.checked`)
    and the registries' factories catch a plugin."""
    try:
        return call()
    except PASSES:
        raise
    except passes:
        raise
    except BaseException as exc:
        raise PluginError(plugin, f"{what} raised {raised(exc)}") from exc


def json_plain(value: Any, at: str = "", depth: int = 0) -> Any:
    """``value``, what a plugin handed over for a JSON record, as plain JSON values — a copy the plugin
    can no longer change (dicts keyed by strings, lists, strings, numbers, bools, None; numpy scalars and
    arrays as numbers and lists) — or TypeError (not JSON) or ValueError (nested beyond
    :data:`MAX_DEPTH`, a number JSON cannot write) saying where in it (``at``: its place so far)."""
    if value is None or type(value) in (str, bool, float):
        return value
    if type(value) is int:
        if value.bit_length() > 256:  # json writes it as text: Python refuses 4300+ digits (ValueError)
            raise ValueError(f"{at or 'it'} is an integer of {value.bit_length()} bits")
        return value
    if depth >= MAX_DEPTH:
        raise ValueError(f"{at[:60]}… is nested more than {MAX_DEPTH} deep")
    if isinstance(value, dict):
        out = {}
        for key, item in value.items():
            if type(key) is not str:
                raise TypeError(f"{at or 'it'} has a key {describe_value(key)}, not a string")
            out[key] = json_plain(item, f"{at}[{key!r}]", depth + 1)
        return out
    if isinstance(value, (list, tuple)):
        return [json_plain(item, f"{at}[{i}]", depth + 1) for i, item in enumerate(value)]
    if hasattr(value, "dtype") and hasattr(value, "tolist"):  # a numpy scalar or array
        return json_plain(value.tolist(), at, depth + 1)
    for plain in (int, float, str):  # a subclass (an IntEnum, a StrEnum): its plain value
        if isinstance(value, plain):
            return json_plain(plain(value), at, depth + 1)
    raise TypeError(f"{at or 'it'} is {describe_value(value)}, not JSON")


AMBIGUOUS = "ambiguous: "
"""How :meth:`Registry.target` marks a name two installed entry points give different targets."""

# an entry point's value: "module", "module:attr" or "module:attr.sub", with optional extras "[a, b]"
_TARGET = re.compile(r"^\s*(?P<module>[\w.]+)\s*(?::\s*(?P<attr>[\w.]+)\s*)?(?:\[[^\]]*\]\s*)?$")


def describe_value(value: Any) -> str:
    """What a plugin returned, in a few words for its :class:`PluginError`: an array's shape, else its type
    and a short repr."""
    if type(value).__name__ == "ndarray" and isinstance(getattr(value, "shape", None), tuple):
        return f"an array of shape {value.shape}"
    try:
        text = " ".join(repr(value).split())
    except Exception:  # its __repr__ is the plugin's too: the error is said without it
        text = "(whose repr raises)"
    return f"{type(value).__name__} {text[:60]}{'…' if len(text) > 60 else ''}"


class Registry:
    """Names → ``"module:attribute"``: ``builtin`` first, then the entry points of ``group`` (read once,
    on first use; a built-in name or one :meth:`register` set wins), names compared in lower case. Two
    entry points that give one name (in any case) different targets make it ambiguous: :meth:`load`
    refuses it, naming both, rather than picking whichever ``sys.path`` lists first."""

    def __init__(self, group: str, builtin: dict[str, str]) -> None:
        self.group = group
        self._targets = {name.lower(): target for name, target in builtin.items()}
        self._discovered = False
        self.unreadable: list[str] = []
        """The installed distributions whose entry points could not be read (``"name (why)"``), passed
        over by :meth:`_discover` and said by :meth:`known`."""

    def _discover(self) -> None:
        """Read the entry points, once: marked read only once they are, so that a reading cut short (a
        run's wall budget, Ctrl-C) is read again next time — it was marked first, and every later run of
        that campaign worker found no emulator: "unknown transport scheme 'emu'".

        An installed distribution whose entry points cannot be read (a line of its ``entry_points.txt``
        without ``=``, in any group) is passed over and listed in :attr:`unreadable`: it ended every
        ``hil run`` — the default one too, whose emulator is an entry point — in a raw TypeError. An entry
        point whose value is no ``module:attribute`` is kept as written, for :meth:`load` to refuse when it
        is chosen (it was an AttributeError from ``importlib.metadata`` for every name of the group)."""
        if self._discovered:
            return
        import importlib.metadata  # only here: reading the entry points costs a run that needs none 10+ ms

        try:
            entries = [
                (e.name, e.value, str(getattr(e.dist, "name", None) or "?"))
                for e in importlib.metadata.entry_points(group=self.group)
            ]
            unreadable: list[str] = []
        except PASSES:
            raise
        except Exception:  # one distribution's metadata is broken: each read on its own, it passed over
            entries, unreadable = _entries_by_distribution(self.group)
        found: dict[str, dict[str, str]] = {}  # name -> target -> the distribution that installed it
        for name, value, dist_name in entries:
            target = _normal_target(value)
            found.setdefault(name.lower(), {}).setdefault(target, f"{name} = {target} ({dist_name})")
        self.unreadable = unreadable
        for name, targets in found.items():
            if len(targets) == 1:
                self._targets.setdefault(name, next(iter(targets)))
            else:  # two packages (or one name in two cases) disagree: neither is picked behind one's back
                self._targets.setdefault(name, AMBIGUOUS + " | ".join(sorted(targets.values())))
        self._discovered = True

    def register(self, name: str, target: str) -> None:
        """Add (or replace) ``name``; ``target`` is ``"module:attribute"``."""
        self._targets[name.lower()] = target

    def names(self) -> list[str]:
        """Every name, built in, installed or registered, sorted."""
        self._discover()
        return sorted(self._targets)

    def known(self) -> str:
        """Every name (:meth:`names`) as a list in words for an error about an unknown one, and the
        installed distributions whose entry points could not be read (:attr:`unreadable`): the name asked
        for may be one of theirs."""
        names = ", ".join(self.names())
        if not self.unreadable:
            return names
        return f"{names}; entry points not read from: {', '.join(self.unreadable)}"

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
        """The object ``target`` names (``"module:attribute"``, the attribute dotted as an entry point's may
        be, its extras ``[...]`` ignored), its module imported. ImportError when it cannot be: the module
        missing, raising anything while it is imported (a SyntaxError, its own exception), or a name
        that installed packages disagree on; AttributeError for a missing attribute (the caller words
        them)."""
        if target.startswith(AMBIGUOUS):
            raise ImportError(
                "installed packages disagree on this name (names are compared in lower case): "
                "uninstall one, or pick one with register()"
            )
        match = _TARGET.match(target)
        if match is None:
            raise ImportError(f"{target!r} is not 'module:attribute'")
        module_name, attr = match.group("module"), match.group("attr")
        try:
            obj = importlib.import_module(module_name)
        except (ImportError, *PASSES):
            raise
        except BaseException as exc:  # the plugin's module failed as it ran (a sys.exit() too): not ours
            raise ImportError(f"importing {module_name} raised {raised(exc)}") from exc
        for part in attr.split(".") if attr else ():
            try:
                obj = getattr(obj, part)
            except (AttributeError, *PASSES):
                raise
            except BaseException as exc:  # a module's __getattr__ (a lazy loader), a property: the plugin's
                raise ImportError(f"reading {module_name}:{attr} raised {raised(exc)}") from exc
        return obj


def _entries_by_distribution(group: str) -> tuple[list[tuple[str, str, str]], list[str]]:
    """The entry points of ``group`` (name, value, distribution), read one installed distribution at a
    time, the first on ``sys.path`` of each name as :func:`importlib.metadata.entry_points` takes it; and
    the distributions passed over because their metadata cannot be read (``"name (why)"``)."""
    import importlib.metadata

    entries: list[tuple[str, str, str]] = []
    unreadable: list[str] = []
    seen: set[str] = set()
    for dist in importlib.metadata.distributions():
        dist_name = "?"
        try:
            dist_name = str(dist.metadata["Name"] or "?")
            key = re.sub(r"[-_.]+", "-", dist_name).lower()
            if key in seen and dist_name != "?":
                continue
            seen.add(key)
            entries += [(e.name, e.value, dist_name) for e in dist.entry_points if e.group == group]
        except PASSES:
            raise
        except Exception as exc:  # its metadata's own fault: not every other package's
            unreadable.append(f"{dist_name} ({raised(exc)})")
    return entries, unreadable


def _normal_target(value: str) -> str:
    """An entry point's ``value`` as :data:`_TARGET` reads it, ``"module:attr"`` (spaces and extras
    dropped, as compared with a registry's own targets); as written when it is none, for
    :meth:`Registry.load` to refuse."""
    match = _TARGET.match(value)
    if match is None:
        return value.strip()
    module, attr = match.group("module"), match.group("attr")
    return f"{module}:{attr}" if attr else module
