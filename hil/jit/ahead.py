"""Kernels compiled ahead of time: an extension module per kernel package, built by the install, loaded
without numba.

numba compiles a kernel on its first call in a process and caches the machine code on disk, but even a
cached kernel costs every process ``import numba`` (0.2–0.3 s) and loading its CPU target and the code
(0.25–0.35 s for the host's kernels), before a run's first tick. The install therefore also builds each
kernel package's kernels as they were called from Python during its warm-up (:mod:`hil.runtime.warmup`)
into a CPython extension module with numba's ahead-of-time compiler (``numba.pycc``: the same typing,
lowering and LLVM as the JIT, the same error model, wrappers that release the GIL like ``nogil=True``):
one per *home* (hil's kernels; each package outside hil, e.g. ``firmware_sim.world.models``), named after
the home and the stamp of the sources it was built from (:func:`hil.jit.tree_stamp`), beside numba's cache
(``NUMBA_CACHE_DIR``, else ``hil/jit/__pycache__``), with a JSON table of its exports beside it that
records the module's size and SHA-256: a module that is not the one its table was written with (cut
short, changed, another build's) is refused before it is loaded (:func:`_check_library`).

A call of a :class:`hil.jit.Kernel` from Python then takes the build whose argument types are exactly the
call's (:func:`type_key`: dtype, dimensions, layout and writability of an array; float, int, bool) and
numba's dispatcher for anything else. A build of other sources (an edited kernel package) is never
loaded: its stamp is not the sources'. What the build does not cover — another estimator's kernels,
another argument type, an edit since the install — runs through numba as before, compiled on first use
and cached. Building needs a C compiler and the Python headers (as the protocol's ``_speedups.c`` does);
without them the install's warm-up says so and everything runs through numba.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.machinery
import importlib.util
import json
import logging
import os
import sys
import sysconfig
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from hil.jit import Kernel

logger = logging.getLogger(__name__)

PREFIX = "vscmg_ahead_"
"""Every ahead-of-time module's name starts so: ``vscmg_ahead_<home>_<stamp>``."""
STAMP_CHARS = 16
"""Hex digits of the sources' stamp in a module's name."""
TABLE_SUFFIX = ".json"
SWITCH = "VSCMG_HIL_AHEAD"
"""``VSCMG_HIL_AHEAD=0`` leaves every build unused: every kernel through numba (to compare, or debug)."""

TypeKeys = tuple[str | None, ...]


def type_key(value: object) -> str | None:
    """The type a compiled kernel sees for ``value``, as :func:`numba_type_key` names numba's type of it
    (numba's ``typeof``: a contiguous array is C-layout even when it is Fortran-contiguous too), or None for
    a value no build takes (a list, a tuple, an object)."""
    kind = type(value)
    if kind is float:
        return "float64"
    if kind is int:
        return "int64" if -(2**63) <= value < 2**63 else None  # type: ignore[operator]
    if kind is bool:
        return "bool"
    if kind is np.ndarray:
        flags = value.flags  # type: ignore[attr-defined]
        probe = (value.dtype, value.ndim, flags.num)  # type: ignore[attr-defined]
        key = _ARRAY_KEYS.get(probe)
        if key is None:
            key = _array_key(value, flags)  # type: ignore[arg-type]
            if len(_ARRAY_KEYS) < MAX_ARRAY_KEYS:
                _ARRAY_KEYS[probe] = key
        return key
    if isinstance(value, np.floating | np.integer | np.bool_):
        return np.dtype(kind).name
    return None


def _array_key(value: np.ndarray, flags: Any) -> str:
    """:func:`type_key` of an array, made from its dtype, dimensions and flags."""
    layout = "C" if flags.c_contiguous else "F" if flags.f_contiguous else "A"
    access = "w" if flags.writeable else "r"
    aligned = "" if flags.aligned else "u"
    return f"{value.dtype.str}{value.ndim}{layout}{access}{aligned}"


MAX_ARRAY_KEYS = 256
"""Kinds of array whose :func:`type_key` is kept (beyond them each is made anew: a process that meets
structured dtypes without end keeps no more)."""
_ARRAY_KEYS: dict[tuple[np.dtype[Any], int, int], str] = {}
"""An array's :func:`type_key` by its dtype, dimensions and flags' bits (``flags.num``: contiguity,
alignment, writability), which decide it: a look-up is ~0.2 µs where making the name is ~0.6, and a kernel
called from Python names every argument at every call (the plant's eight, ~2 000 calls a run)."""


def numba_type_key(nbtype: Any) -> str | None:
    """:func:`type_key`'s name for the numba type ``nbtype``, None for one builds do not take."""
    from numba.core import types

    if isinstance(nbtype, types.Array):
        dtype = np.dtype(str(nbtype.dtype))
        access = "w" if nbtype.mutable else "r"
        aligned = "" if nbtype.aligned else "u"
        return f"{dtype.str}{nbtype.ndim}{nbtype.layout}{access}{aligned}"
    if isinstance(nbtype, types.Boolean):
        return "bool"
    if isinstance(nbtype, types.Float | types.Integer):
        return str(nbtype)
    return None


def directory() -> Path:
    """Where builds live: numba's cache directory (``NUMBA_CACHE_DIR``) if set, else ``hil/jit/__pycache__``
    (numba caches beside the sources there)."""
    root = os.environ.get("NUMBA_CACHE_DIR")
    return Path(root) if root else Path(__file__).parent / "__pycache__"


def module_name(home: str | None) -> str:
    """The module name of ``home``'s build for the present sources (None: hil's own kernels)."""
    from hil import jit

    tag = "hil" if home is None else home.replace(".", "_")
    return f"{PREFIX}{tag}_{jit.tree_stamp(home)[:STAMP_CHARS]}"


def _paths(name: str) -> tuple[Path, Path]:
    """(the extension module, its table) for module ``name``."""
    folder = directory()
    return folder / f"{name}{importlib.machinery.EXTENSION_SUFFIXES[0]}", folder / f"{name}{TABLE_SUFFIX}"


def available(home: str | None) -> bool:
    """Whether ``home``'s kernels have a build of the present sources."""
    return bool(_loaded(home)[1])


def exports(module: str, qualname: str, home: str | None) -> dict[TypeKeys, Callable[..., Any]]:
    """The builds of kernel ``module.qualname`` (home ``home``) by argument types; empty when there is no
    build of the present sources, or it has none of this kernel."""
    built, table = _loaded(home)
    if built is None:
        return {}
    return {tuple(keys): getattr(built, export) for export, keys in table.get(f"{module}:{qualname}", ())}


@functools.cache
def _loaded(home: str | None) -> tuple[Any, dict[str, list[tuple[str, list[str]]]]]:
    """``home``'s build of the present sources (the module, its table), loaded once per process; (None, {})
    when there is none, or it cannot be loaded (logged)."""
    if os.environ.get(SWITCH) == "0":
        return None, {}
    name = module_name(home)
    library, table_path = _paths(name)
    if not (library.exists() and table_path.exists()):
        return None, {}
    try:
        document = json.loads(table_path.read_text())
        table = _table(document)
        _check_library(library, document)  # before the loader maps it: a short file kills the process
        spec = importlib.util.spec_from_file_location(name, library)
        assert spec is not None and spec.loader is not None
        built = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(built)
        for entries in table.values():
            for export, _ in entries:
                getattr(built, export)  # every export the table names is there
        sys.modules[name] = built
    except (OSError, ImportError, ValueError, KeyError, TypeError, AttributeError, RecursionError) as exc:
        logger.warning("the kernels' build %s is not usable (numba compiles them instead): %s", library, exc)
        return None, {}
    return built, table


def _library_record(library: Path) -> dict[str, int | str]:
    """What a build's table records of its extension module: its size in bytes and its SHA-256."""
    import hashlib  # here: loaded by the few processes that load a build, ~1 ms for ~0.8 MB

    with library.open("rb") as file:  # size and digest of one file, whatever replaces the path meanwhile
        return {
            "bytes": os.fstat(file.fileno()).st_size,
            "sha256": hashlib.file_digest(file, "sha256").hexdigest(),
        }


def _check_library(library: Path, document: Any) -> None:
    """Raise a ValueError naming what differs unless ``library`` is the extension module the table
    ``document`` was written with (its ``library`` record: size and SHA-256).

    The loader maps an extension module without reading it through: a build cut short (a disk that
    filled, a power cut after the rename and before the data reached the disk, an interrupted copy) killed
    the process with SIGBUS at its first kernel call, with no message; one changed in place could give
    other numbers; a build interrupted between writing the module and writing its table left a module
    beside another build's table. A table without the record (made before it was written) is refused
    too: the next install builds afresh."""
    recorded = document.get("library") if isinstance(document, dict) else None
    if not isinstance(recorded, dict):
        raise ValueError("the table records no size and digest of its module")
    found = _library_record(library)
    if found["bytes"] != recorded.get("bytes"):
        raise ValueError(f"the module is {found['bytes']} bytes, its table says {recorded.get('bytes')}")
    if found["sha256"] != recorded.get("sha256"):
        raise ValueError("the module's SHA-256 is not its table's (changed since it was built)")


def _table(document: Any) -> dict[str, list[tuple[str, list[str]]]]:
    """A build's table (``{"kernels": {"module:qualname": [[export, [type key, ...]], ...]}, "library":
    {"bytes": ..., "sha256": ...}}``, the latter checked by :func:`_check_library`) checked for the former's
    shape; a ValueError names what is not."""
    table = document.get("kernels") if isinstance(document, dict) else None
    if not isinstance(table, dict):
        raise ValueError("the table has no 'kernels' object")
    for kernel, entries in table.items():
        if not isinstance(entries, list) or not all(
            isinstance(entry, list)
            and len(entry) == 2
            and isinstance(entry[0], str)
            and isinstance(entry[1], list)
            and all(isinstance(key, str) for key in entry[1])
            for entry in entries
        ):
            raise ValueError(f"the table's entry for {kernel} is not a list of [export, [types]]")
    return table


def build(home: str | None, kernels: Sequence[Kernel]) -> Path | None:
    """Build ``home``'s kernels that were called from Python in this process, for every argument types
    numba compiled them for, as an extension module in :func:`directory` (older builds of the home
    removed); the module's path, or None when no kernel was called. Raises what the compiler raises."""
    import tempfile  # here, where the install builds: not in every process that loads a build (~2 ms)

    entries = _entries(kernels)
    if not entries:
        return None
    name = module_name(home)
    library, table_path = _paths(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numba.pycc's pending deprecation
        from numba.pycc import CC
    compiler = CC(name)
    compiler.verbose = False
    table: dict[str, list[tuple[str, list[str]]]] = {}
    for number, (kernel, signature, keys) in enumerate(entries):
        export = f"k{number}"
        compiler.export(export, signature)(kernel.py_func)
        table.setdefault(f"{kernel.__module__}:{kernel.__qualname__}", []).append((export, keys))
    library.parent.mkdir(parents=True, exist_ok=True)
    _remove_abandoned_scratch(library.parent)
    with (
        tempfile.TemporaryDirectory(dir=library.parent, prefix=SCRATCH_PREFIX) as scratch,
        _wrappers_release_the_gil(),
    ):
        compiler.output_dir = scratch
        compiler.compile()
        staged_library = Path(scratch) / library.name
        record = _library_record(staged_library)
        os.replace(staged_library, library)
        staged = Path(scratch) / table_path.name
        staged.write_text(json.dumps({"kernels": table, "library": record}, indent=1))
        os.replace(staged, table_path)
    _remove_stale(name)
    _loaded.cache_clear()
    return library


def _entries(kernels: Sequence[Kernel]) -> list[tuple[Kernel, Any, list[str]]]:
    """(kernel, numba signature with its return type, argument type keys) of each compiled version of each
    kernel called from Python, in the kernels' order."""
    entries = []
    for kernel in kernels:
        if not kernel.from_python:  # never called from Python here, or only through a build
            continue
        dispatcher = kernel.dispatcher
        for args in dispatcher.signatures:
            keys = [numba_type_key(t) for t in args]
            if any(key is None for key in keys):
                continue
            signature = dispatcher.overloads[args].signature
            entries.append((kernel, signature.return_type(*args), [str(k) for k in keys]))
    return entries


SCRATCH_PREFIX = "hil-build-"
"""The name a build's scratch directory (beside the builds) starts with."""
ABANDONED_AFTER_S = 3600.0
"""A scratch directory untouched this long (s) is a build's that was killed (SIGKILL, a power cut: its
clean-up never ran), not one under way (a build takes a minute at most): the next build removes it."""


def _remove_abandoned_scratch(builds: Path) -> None:
    """Remove the scratch directories in ``builds`` that builds killed part-way left (each a compiler's
    object files and a half-made module, ~1 MB): an install interrupted again and again filled the cache
    with them."""
    import shutil
    import time

    for path in builds.glob(f"{SCRATCH_PREFIX}*"):
        with contextlib.suppress(OSError):
            if path.is_dir() and time.time() - path.stat().st_mtime > ABANDONED_AFTER_S:
                shutil.rmtree(path)


def _remove_stale(name: str) -> None:
    """Remove the home's builds of other sources than ``name``'s."""
    stem = name[: -STAMP_CHARS - 1]
    for path in directory().glob(f"{stem}_*"):
        if not path.name.startswith(f"{name}.") and len(path.name.split(".")[0]) == len(name):
            with contextlib.suppress(OSError):
                path.unlink()


@contextlib.contextmanager
def _wrappers_release_the_gil() -> Iterator[None]:
    """numba.pycc compiles its exports with default flags; its wrappers release the GIL as a ``nogil=True``
    dispatcher's do (a world thread beside the control loop), with this flag set for the build."""
    import numba.pycc.compiler as pycc_compiler

    flags_class = pycc_compiler.Flags

    class ReleasingFlags(flags_class):  # type: ignore[misc, valid-type]
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.release_gil = True

    setattr(pycc_compiler, "Flags", ReleasingFlags)  # noqa: B010 — a module's class swapped for the build
    try:
        yield
    finally:
        setattr(pycc_compiler, "Flags", flags_class)  # noqa: B010


def can_build() -> bool:
    """Whether this machine can build an extension module: a C compiler on the PATH and the Python headers
    (numba.pycc compiles its helpers with them; Debian's ``gcc`` and ``python3-dev``)."""
    import shutil  # here, where the install builds: not in every process that loads a build (~2 ms)

    compiler = any(shutil.which(cc) for cc in (os.environ.get("CC") or "cc", "gcc", "clang"))
    return compiler and (Path(sysconfig.get_paths()["include"]) / "Python.h").exists()


def loaded_modules() -> list[str]:
    """The builds loaded in this process (module names), for reports and tests."""
    return sorted(name for name in sys.modules if name.startswith(PREFIX))
