"""Kernels built ahead of time (hil.jit.ahead): a call takes a build only for exactly the argument types it
was built for, named as numba names them; a build of other sources, or one that does not load, is never
used. (That a build gives numba's bits, and that a run with the builds loads no numba: test_warmup.py and
test_lazy_imports.py.)"""

from __future__ import annotations

import logging
import shutil

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from hil import jit
from hil.control import steering
from hil.jit import ahead
from hil.scenario import load_scenario

pytestmark = pytest.mark.skipif(not jit.COMPILED, reason="compiling is switched off (NUMBA_DISABLE_JIT=1)")

DTYPES = st.sampled_from([np.float64, np.float32, np.int64, np.int32, np.bool_, np.uint8, np.complex128])


@st.composite
def arrays(draw: st.DrawFn) -> np.ndarray:
    """Arrays of every layout numba tells apart: C, Fortran, neither (a strided view), read-only."""
    a = draw(hnp.arrays(DTYPES, hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4)))
    view = draw(st.sampled_from(["as is", "fortran", "strided", "transposed"]))
    if view == "fortran":
        a = np.asfortranarray(a)
    elif view == "strided" and a.ndim and a.shape[0] > 1:
        a = a[::2]
    elif view == "transposed":
        a = a.T
    if draw(st.booleans()):
        a = a.copy() if not a.flags.writeable else a
        a.flags.writeable = False
    return a


SCALARS = st.one_of(
    st.floats(allow_nan=True),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.booleans(),
    st.sampled_from([np.float64(1.5), np.float32(2.0), np.int64(3), np.int32(-4), np.bool_(True)]),
)


@settings(max_examples=300, deadline=None)
@given(st.one_of(arrays(), SCALARS))
def test_a_values_key_is_the_name_of_numbas_type_of_it(value):
    expected = ahead.numba_type_key(numba.typeof(value))
    assert ahead.type_key(value) == expected


@settings(max_examples=200, deadline=None)
@given(arrays(), st.booleans())
def test_an_arrays_kept_key_follows_its_flags(value, misaligned):
    """The key kept for a kind of array (:data:`ahead.MAX_ARRAY_KEYS`) is the one made anew, for the same
    array after its writability changes, and for a misaligned copy of it (a raw buffer one byte in), which
    numba's ``typeof`` calls aligned: its key says unaligned, so that no build (compiled for aligned
    arrays) takes it."""
    made = ahead._array_key(value, value.flags)
    assert ahead.type_key(value) == ahead.type_key(value) == made == ahead.numba_type_key(numba.typeof(value))
    if value.flags.writeable and value.flags.owndata:
        value.flags.writeable = False
        assert ahead.type_key(value) == ahead.numba_type_key(numba.typeof(value))
        value.flags.writeable = True
        assert ahead.type_key(value) == made
    if misaligned and value.dtype.itemsize > 1 and value.size:
        raw = np.zeros(value.nbytes + 1, np.uint8)[1:]
        odd = raw.view(value.dtype).reshape(value.shape)
        assert not odd.flags.aligned
        key = ahead.type_key(odd)
        assert key == ahead._array_key(odd, odd.flags) and key.endswith("wu")
        assert key[:-1] == ahead.numba_type_key(numba.typeof(odd))  # all but the alignment


def test_the_kept_keys_are_bounded(monkeypatch: pytest.MonkeyPatch):
    """Arrays of ever new (structured) dtypes keep at most :data:`ahead.MAX_ARRAY_KEYS` keys, and each
    array past the bound is still named."""
    monkeypatch.setattr(ahead, "_ARRAY_KEYS", {})
    for i in range(ahead.MAX_ARRAY_KEYS + 50):
        a = np.zeros(2, dtype=[(f"f{i}", np.float64)])
        assert ahead.type_key(a) == ahead._array_key(a, a.flags)
    assert len(ahead._ARRAY_KEYS) == ahead.MAX_ARRAY_KEYS


@pytest.mark.parametrize("value", [[1.0, 2.0], (1.0, 2.0), "x", None, object(), 2**70, 1 + 2j])
def test_a_value_no_build_takes_has_no_key(value):
    assert ahead.type_key(value) is None


def _use_cache(monkeypatch: pytest.MonkeyPatch, folder) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(folder))
    ahead._loaded.cache_clear()
    monkeypatch.setattr(steering.momentum_rows, "_ahead", None)


def test_without_a_build_of_the_present_sources_a_kernel_runs_through_numba(monkeypatch, tmp_path, caplog):
    """An empty cache; files of another stamp; under the present name an unloadable file, a table of the
    wrong shape, a real build whose table names an export it lacks: each time no build is taken (the
    last three logged), and the kernel's call gives numba's result."""
    name = ahead.module_name(None)
    library, table = ahead._paths(name)
    built_here = library  # where the install put hil's build, before the cache moves below
    scenario = load_scenario()
    geom = steering.VscmgSteering(scenario.spacecraft, scenario.loop.steering)._geom
    gam, w = np.array([[0.1, 0.2, 0.3, 0.4]]), np.array([[500.0, 510.0, 490.0, 505.0]])
    expected = steering.momentum_rows.py_func
    for step in ("empty", "other stamp", "unloadable", "bad table", "table naming no such export"):
        folder = tmp_path / step
        folder.mkdir()
        if step == "other stamp":
            (folder / library.name.replace(name, name[:-4] + "0000")).write_bytes(b"\x7fELF")
            (folder / table.name.replace(name, name[:-4] + "0000")).write_text('{"kernels": {}}')
        if step == "unloadable":
            (folder / library.name).write_bytes(b"not a shared object")
            (folder / table.name).write_text('{"kernels": {"hil.control.steering:momentum_rows": []}}')
        if step == "bad table":
            (folder / library.name).write_bytes(b"not a shared object")
            (folder / table.name).write_text('{"kernels": {"hil.control.steering:momentum_rows": [["k0"]]}}')
        if step == "table naming no such export":
            if not built_here.exists():  # the install's build of these sources (CI's always has one)
                continue
            shutil.copy(built_here, folder / library.name)
            (folder / table.name).write_text(
                '{"kernels": {"hil.control.steering:momentum_rows": [["k99", ["<f82Cw"]]]}}'
            )
        _use_cache(monkeypatch, folder)
        with caplog.at_level(logging.WARNING, logger="hil.jit.ahead"):
            assert not ahead.available(None)
            assert steering.momentum_rows.ahead_of_time(("<f82Cw",) * 4) is None
        assert ("not usable" in caplog.text) == (step not in ("empty", "other stamp")), caplog.text
        out_numba = np.zeros((1, 3))
        out_python = np.zeros((1, 3))
        steering.momentum_rows(geom, gam, w, out_numba)
        expected(geom, gam, w, out_python)
        assert np.array_equal(out_numba, out_python) and np.abs(out_python).max() > 0
        caplog.clear()


def test_the_switch_leaves_every_build_unused(monkeypatch):
    monkeypatch.setenv(ahead.SWITCH, "0")
    ahead._loaded.cache_clear()
    try:
        assert ahead._loaded(None) == (None, {})
    finally:
        monkeypatch.delenv(ahead.SWITCH)
        ahead._loaded.cache_clear()


def test_a_kernel_pickles_and_copies_by_name():
    """A kernel travels by name, as a function does (a campaign's task, a deep copy): the same object back,
    whatever it has loaded (numba's dispatcher, an ahead-of-time module, which pickles by neither)."""
    import copy
    import pickle

    from firmware_sim.world.models import kernels

    for kernel in (steering.momentum_rows, kernels.advance):
        assert pickle.loads(pickle.dumps(kernel)) is kernel
        assert copy.deepcopy(kernel) is kernel and copy.copy(kernel) is kernel


def test_a_build_that_cannot_be_made_leaves_the_kernels_to_numba(monkeypatch, caplog):
    """No C compiler or Python headers, or a compiler error: the install's warm-up says so and builds
    nothing (the kernels run through numba); it never fails."""
    from hil.runtime import warmup

    monkeypatch.setattr(steering.momentum_rows, "from_python", True)  # a candidate for hil's build
    monkeypatch.setattr(ahead, "available", lambda home: False)
    monkeypatch.setattr(ahead, "can_build", lambda: False)
    with caplog.at_level(logging.WARNING, logger="hil.runtime.warmup"):
        assert warmup.build_ahead(lambda home: home is None) == []
    assert "no C compiler or Python headers" in caplog.text
    caplog.clear()

    def broken(home, kernels):
        raise RuntimeError("cc: internal compiler error")

    monkeypatch.setattr(ahead, "can_build", lambda: True)
    monkeypatch.setattr(ahead, "build", broken)
    with caplog.at_level(logging.WARNING, logger="hil.runtime.warmup"):
        assert warmup.build_ahead(lambda home: home is None) == []
    assert "ahead of time failed: cc: internal compiler error" in caplog.text


def test_a_keyword_call_runs_through_numba():
    scenario = load_scenario()
    geom = steering.VscmgSteering(scenario.spacecraft, scenario.loop.steering)._geom
    gam, w = np.array([[0.1, 0.2, 0.3, 0.4]]), np.array([[500.0, 510.0, 490.0, 505.0]])
    by_keyword, positional = np.zeros((1, 3)), np.zeros((1, 3))
    steering.momentum_rows(geom, gam, w=w, out=by_keyword)
    steering.momentum_rows(geom, gam, w, positional)
    assert np.array_equal(by_keyword, positional) and np.abs(positional).max() > 0
