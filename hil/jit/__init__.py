"""Compiled kernels: the project's one switch between compiled and interpreted numerics.

Each hot kernel (the estimator's inner loop, steering's pseudo-inverse; on the far side the plant step, the
drive models, the simulated phone) is written once, in the subset of Python that numba compiles, and decorated
with :func:`kernel`; its numpy reference lives beside it and the tests compare the two. A :class:`Kernel`
runs the build the install made of it ahead of time (:mod:`hil.jit.ahead`: an extension module, loaded
without numba) when there is one for the call's argument types; otherwise numba compiles it on its first
call and caches the machine code on disk (``__pycache__`` beside the source, or ``NUMBA_CACHE_DIR``), so
only a fresh install's first run pays for compiling. numba itself is imported only then: a process whose
kernels are all built never imports it (~0.5 s of every process's start with it).

numba invalidates a cached kernel when *its own* source file changes, not when a function it calls from
another file does (numba issue #1833): a kernel in one module calling one in another would then run the
callee's old machine code. The cache of every :func:`kernel` is therefore stamped with a hash of all the
sources of the packages hil's kernels live in (:data:`STAMPED`): editing any of them recompiles them all.
A kernel that lives outside them (the world's, :mod:`firmware_sim.world.models`, which call hil's but are
never called by them) is stamped with its own package's sources too. Reading those sources (from the
packages' folders, once per process and package) is this package's only I/O besides numba's own cache
files.

numba's CPU target, when it first loads (a kernel's first call in a process), imports
``numba.np.arraymath``, which imports ``scipy.linalg`` only to learn whether a BLAS is there (its
``_check_blas``; the answer picks a BLAS or a plain loop for ``np.correlate``/``np.convolve``, which no
kernel here uses). All of ``scipy.linalg`` (numpy.testing, scipy's array-API layer) is 0.1–0.3 s of a
process's start, 1.2 s on a loaded machine: :class:`_BlasProbeDeclined` answers that one probe "no BLAS",
once, and steps aside; a kernel that really calls BLAS (``np.dot``, ``np.linalg``) still imports it where
numba compiles that call (``ensure_blas``), and so does anyone else who imports scipy.

A per-sample caller (the estimator's ``update``, the filter's ``step``) calls its kernel's machine code
through :func:`direct`, without numba's dispatcher: the dispatcher types every argument on every call to
choose a compiled version, ~0.2 µs of a 12-argument call, a tenth of a sample's whole budget; a caller whose
argument types never change needs that choice made once.

``NUMBA_DISABLE_JIT=1`` (numba's own switch) turns every kernel back into the plain Python it is written
in: slower, but steppable in a debugger, with Python's tracebacks. :data:`COMPILED` says which is in force.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import logging
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from importlib.machinery import ModuleSpec
from pathlib import Path
from types import ModuleType
from typing import Any, TypeVar, cast

from . import ahead

logger = logging.getLogger(__name__)

F = TypeVar("F", bound=Callable[..., Any])


def _jit_disabled(value: str | None) -> bool:
    """``NUMBA_DISABLE_JIT`` as numba's own configuration reads it (an integer, 0 when unset or empty)."""
    try:
        return bool(int(value or 0))
    except ValueError:
        return False


COMPILED: bool = not _jit_disabled(os.environ.get("NUMBA_DISABLE_JIT"))
"""False when ``NUMBA_DISABLE_JIT=1``: every kernel runs as plain Python. Read from the environment as
numba reads it, so that deciding does not import numba."""

STAMPED = ("so3", "estimation", "vscmg", "control", "jit")
"""The packages of ``hil`` whose sources stamp every kernel's cache: where hil's kernels and their callees
live."""


BLAS_PROBE = ("numba.np.arraymath", "_check_blas")
"""The module and function of numba's import-time BLAS probe (:class:`_BlasProbeDeclined`)."""


class _BlasProbeDeclined:
    """Refuses ``import scipy.linalg`` to numba's BLAS probe (:data:`BLAS_PROBE`) alone, once, then takes
    itself off ``sys.meta_path``: every other import of scipy.linalg, before or after, is untouched. A
    numba whose probe is named otherwise never meets it (and pays the import as before). A meta path
    finder by its ``find_spec`` alone: :class:`importlib.abc.MetaPathFinder` would import
    :mod:`importlib.resources` (and tempfile, shutil, random) into every process, ~4 ms of its start."""

    MAX_DEPTH = 40
    """Frames searched up from the import for the probe (the import machinery's own are ~10)."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: object = None
    ) -> ModuleSpec | None:
        if fullname != "scipy.linalg" or not _called_from(*BLAS_PROBE, self.MAX_DEPTH):
            return None
        _uninstall_blas_probe_guard()
        raise ImportError("hil.jit: numba's BLAS probe answered 'no' (no kernel uses np.correlate)")


def _called_from(module: str, function: str, max_depth: int) -> bool:
    """Whether ``module.function`` is on the calling thread's stack within ``max_depth`` frames."""
    frame = sys._getframe(1)
    for _ in range(max_depth):
        if frame is None:
            return False
        if frame.f_code.co_name == function and frame.f_globals.get("__name__") == module:
            return True
        frame = frame.f_back  # type: ignore[assignment]
    return False


_BLAS_PROBE_GUARD = _BlasProbeDeclined()


def _install_blas_probe_guard() -> None:
    """The guard on ``sys.meta_path``, unless numba's probe has already run or scipy.linalg is loaded."""
    if BLAS_PROBE[0] not in sys.modules and "scipy.linalg" not in sys.modules:
        sys.meta_path.insert(0, _BLAS_PROBE_GUARD)


def _uninstall_blas_probe_guard() -> None:
    if _BLAS_PROBE_GUARD in sys.meta_path:
        sys.meta_path.remove(_BLAS_PROBE_GUARD)


if COMPILED:
    _install_blas_probe_guard()


class Kernel:
    """A kernel: ``py_func`` compiled in nopython mode, cached on disk, releasing the GIL while it runs (so a
    world thread and the host's control loop can run side by side in real time).

    Nothing is imported or compiled until the kernel is first called from Python or named by another
    kernel being compiled. A call from Python runs the kernel's ahead-of-time build for the call's
    argument types when the install made one (:mod:`hil.jit.ahead`: no numba in the process at all), and
    numba's dispatcher otherwise (:attr:`dispatcher`, created then, numba imported then). Any other
    attribute (``signatures``, ``stats``, ``compile``, ...) is the dispatcher's."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.py_func = fn
        self.__name__ = fn.__name__
        self.__qualname__ = fn.__qualname__
        self.__module__ = fn.__module__
        self.__doc__ = fn.__doc__
        self._dispatcher: Any = None
        self._ahead: dict[tuple[str | None, ...], Callable[..., Any]] | None = None
        self.from_python = False
        """Whether numba's dispatcher was called from Python (or bound by :func:`direct`) in this process:
        what the ahead-of-time build exports (not the kernels it compiled only as others' callees)."""
        _KERNELS.append(self)

    @property
    def dispatcher(self) -> Any:
        """numba's dispatcher of :attr:`py_func` (created, and numba imported, on first use)."""
        dispatcher = self._dispatcher
        if dispatcher is None:
            dispatcher = self._dispatcher = _dispatcher_of(self.py_func)
        return dispatcher

    @property
    def loaded(self) -> bool:
        """Whether machine code of it is in this process: its ahead-of-time build (looked up at its first
        call from Python, or by :func:`direct`), or numba's compiled for some argument types."""
        return self.versions > 0

    @property
    def versions(self) -> int:
        """How many versions (argument types) of its machine code are in this process: ahead-of-time
        builds looked up, and numba's compiled or loaded."""
        numba_versions = len(self._dispatcher.signatures) if self._dispatcher is not None else 0
        return len(self._ahead or ()) + numba_versions

    def ahead_of_time(self, types: tuple[str | None, ...]) -> Callable[..., Any] | None:
        """The ahead-of-time build of this kernel for argument types ``types`` (:func:`ahead.type_key`s),
        or None."""
        table = self._ahead
        if table is None:
            table = self._ahead = ahead.exports(self.__module__, self.__qualname__, home(self.py_func))
        return table.get(types) if table else None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if not kwargs and (self._ahead is None or self._ahead):  # a build takes positional arguments
            built = self.ahead_of_time(tuple(map(ahead.type_key, args)))
            if built is not None:
                return built(*args)
        self.from_python = True
        return self.dispatcher(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("_dispatcher", "_ahead", "py_func", "from_python"):
            raise AttributeError(name)  # copy's and pickle's probes, or a kernel half made
        return getattr(self.dispatcher, name)

    def __repr__(self) -> str:
        return f"<hil.jit.Kernel {self.__module__}.{self.__qualname__}>"

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled (and copied) by name, as a function is: neither numba's dispatcher nor a function of an
        ahead-of-time module travels."""
        return (_kernel_named, (self.__module__, self.__qualname__))


def _kernel_named(module: str, qualname: str) -> Kernel:
    """The kernel ``module.qualname``, imported."""
    found: Any = importlib.import_module(module)
    for part in qualname.split("."):
        found = getattr(found, part)
    return cast(Kernel, found)


_KERNELS: list[Kernel] = []
"""Every kernel defined in this process, in definition order (the ahead-of-time build's candidates)."""


def kernels() -> list[Kernel]:
    """Every kernel defined (its module imported) in this process, in definition order."""
    return list(_KERNELS)


_JITABLE: list[Callable[..., Any]] = []
"""Plain functions :func:`jitable` marked before numba was imported (registered with it then)."""


def kernel(fn: F) -> F:
    """``fn`` as a :class:`Kernel` (``fn`` itself when compiling is switched off)."""
    if not COMPILED:
        return fn
    return cast(F, Kernel(fn))


def jitable(fn: F) -> F:
    """``fn`` unchanged, and callable from inside compiled kernels too (numba's ``register_jitable``: numba
    compiles it into its caller), registered when numba is first imported."""
    if COMPILED:
        if _numba.cache_info().currsize:
            _numba().extending.register_jitable(fn)
        else:
            _JITABLE.append(fn)
    return fn


@functools.cache
def _numba() -> ModuleType:
    """numba, imported on first need, taught to type a :class:`Kernel` named inside another kernel as its
    dispatcher, with the :func:`jitable` functions registered."""
    import numba
    import numba.extending
    from numba.core import types

    @numba.extending.typeof_impl.register(Kernel)
    def _typeof_kernel(value: Kernel, context: Any) -> Any:
        return types.Dispatcher(value.dispatcher)

    for fn in _JITABLE:
        numba.extending.register_jitable(fn)
    _JITABLE.clear()
    return numba


def _dispatcher_of(fn: Callable[..., Any]) -> Any:
    """numba's dispatcher of ``fn``: nopython, nogil, its disk cache stamped (:func:`_cache_class`)."""
    numba = _numba()
    dispatcher = numba.njit(nogil=True)(fn)
    cache = _cache_class(home(fn))
    if cache is None:  # a numba without the locator API this relies on: numba's own per-file stamp
        dispatcher.enable_caching()
    else:
        dispatcher._cache = cache(dispatcher.py_func)  # as enable_caching()
    return dispatcher


def direct(fn: F, *examples: Any) -> F:
    """The kernel ``fn`` for the types of ``examples``, as a callable that skips numba's per-call dispatch:
    its ahead-of-time build when there is one (:mod:`hil.jit.ahead`), else compiled (or loaded from the
    cache) by numba. Each argument is converted as the example's type is (a float argument takes any
    Python number); arrays must have the examples' dtype, dimensions and layout, which nothing checks: for
    callers that pass their own arrays. ``fn`` itself when compiling is off."""
    if not COMPILED:
        return fn
    kernel_ = cast(Kernel, fn)
    built = kernel_.ahead_of_time(tuple(map(ahead.type_key, examples)))
    if built is not None:
        return cast(F, built)
    numba = _numba()
    kernel_.from_python = True
    return cast(F, kernel_.dispatcher.compile(tuple(numba.typeof(a) for a in examples)))


def home(fn: Callable[..., Any]) -> str | None:
    """The package of a kernel that lives outside ``hil`` (its sources stamp its cache beside
    :data:`STAMPED`'s), or None for one of hil's own."""
    package = fn.__module__.rpartition(".")[0]
    return None if package.partition(".")[0] == "hil" else package


@functools.cache
def tree_stamp(home: str | None = None) -> str:
    """SHA-256 of the sources of :data:`STAMPED` (names and contents) and, for a kernel that lives outside
    hil, of its package ``home`` (dotted, e.g. ``firmware_sim.world.models``); computed once per process."""
    digest = hashlib.sha256()
    for package in STAMPED:
        for name, source in _sources(_folder("hil") / package, f"hil/{package}"):
            digest.update(name.encode())
            digest.update(source)
    if home is not None:
        for name, source in _sources(_folder(home), home.replace(".", "/")):
            digest.update(name.encode())
            digest.update(source)
    return digest.hexdigest()


def _folder(package: str) -> Path:
    """The folder of ``package`` (dotted; imported if it is not yet), where its sources are."""
    return Path(importlib.import_module(package).__path__[0])


def _sources(folder: Path, name: str) -> Iterator[tuple[str, bytes]]:
    """``(name, bytes)`` of every ``.py`` file under ``folder``, sorted by name."""
    for entry in sorted(folder.iterdir(), key=lambda e: e.name):
        if entry.is_dir():
            yield from _sources(entry, f"{name}/{entry.name}")
        elif entry.name.endswith(".py"):
            yield f"{name}/{entry.name}", entry.read_bytes()


@functools.cache
def _cache_class(home: str | None) -> type | None:
    """numba's function cache with its two source-file locators stamped by :func:`tree_stamp` (of
    ``home`` too, for a kernel outside hil)."""
    try:
        from numba.core import caching

        in_tree, user_dir = caching.InTreeCacheLocator, caching.UserProvidedCacheLocator
        impl, function_cache = caching.CompileResultCacheImpl, caching.FunctionCache
    except (ImportError, AttributeError):
        return None

    def stamped(base: Any) -> type:
        def get_source_stamp(self: Any) -> object:
            return (base.get_source_stamp(self), tree_stamp(home))

        return type(f"Stamped{base.__name__}", (base,), {"get_source_stamp": get_source_stamp})

    locators = [stamped(user_dir), stamped(in_tree), *impl._locator_classes]
    stamped_impl = type("StampedCacheImpl", (impl,), {"_locator_classes": locators})
    return type(
        "StampedFunctionCache", (_CheckedFunctionCache, function_cache), {"_impl_class": stamped_impl}
    )


class _CheckedFunctionCache:
    """numba's function cache (the class after it in a subclass's bases) made to survive its own files.

    numba unpickles its index (``.nbi``) and data (``.nbc``) files unchecked and writes them unguarded: a
    file cut short (a disk that filled, a power cut after numba's rename and before the data reached the
    disk, an interrupted copy of the cache), emptied, replaced by a directory or by anything else raised
    ``UnpicklingError``/``EOFError``/``IsADirectoryError`` out of a kernel's first call, in every run
    until the file was deleted by hand; a cache that cannot be written (a full disk) raised after the
    compile. Here an unreadable index counts as an empty one and an unreadable entry as a missing one
    (both logged with their folder): the kernel is compiled again, and saving it rewrites the files. A
    save that fails is logged and the compiled kernel runs: the next process compiles it again."""

    _impl: Any
    _py_func: Callable[..., Any]
    _cache_path: str
    _cache_file: Any

    def __init__(self, py_func: Callable[..., Any]) -> None:
        super().__init__(py_func)  # type: ignore[call-arg]
        unchecked: Any = type(self._cache_file)
        self._cache_file = _checked_cache_file(unchecked)(
            cache_path=self._cache_path,
            filename_base=self._impl.filename_base,
            source_stamp=self._impl.locator.get_source_stamp(),
        )

    @property
    def _kernel_name(self) -> str:
        return f"{self._py_func.__module__}.{self._py_func.__qualname__}"

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        try:
            return super().load_overload(sig, target_context)  # type: ignore[misc]
        except Exception as exc:  # an entry that unpickles to what numba cannot rebuild: anything
            logger.warning(
                "numba's cache of %s in %s is not usable (compiled again): %s: %s",
                self._kernel_name, self._cache_path, type(exc).__name__, exc,
            )  # fmt: skip
            return None

    def save_overload(self, sig: Any, data: Any) -> None:
        try:
            super().save_overload(sig, data)  # type: ignore[misc]
        except OSError as exc:  # a full disk, a read-only or vanished folder, a directory in a file's place
            logger.warning(
                "cannot save %s in numba's cache %s (each process compiles it again): %s",
                self._kernel_name, self._cache_path, exc,
            )  # fmt: skip


@functools.cache
def _checked_cache_file(unchecked: Any) -> type:
    """numba's index-and-data cache file ``unchecked`` whose index, when it cannot be read or unpickled,
    counts as empty (as numba counts one of another numba version), logged with its path."""

    def _load_index(self: Any) -> dict[Any, Any]:
        try:
            return cast(dict[Any, Any], unchecked._load_index(self))
        except Exception as exc:  # unpickling a truncated or foreign file raises anything
            logger.warning(
                "numba's cache index %s is not usable (compiled again, the index rewritten): %s: %s",
                self._index_path, type(exc).__name__, exc,
            )  # fmt: skip
            return {}

    return type(f"Checked{unchecked.__name__}", (unchecked,), {"_load_index": _load_index})


__all__ = ["COMPILED", "STAMPED", "Kernel", "direct", "home", "jitable", "kernel", "kernels", "tree_stamp"]
