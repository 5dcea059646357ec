"""fluidsim.host_copy.rows_to_numpy: the same array as Taichi's ``to_numpy()[:n]`` for scalar and vector ndarrays of
every type the engine keeps, and a refused row count."""

import numpy as np
import pytest
import taichi as ti

from fluidsim.host_copy import rows_to_numpy


@pytest.mark.parametrize(
    "make",
    [
        lambda: ti.Vector.ndarray(3, ti.f32, shape=7),
        lambda: ti.Vector.ndarray(3, ti.f64, shape=7),
        lambda: ti.Vector.ndarray(6, ti.f64, shape=7),
        lambda: ti.ndarray(ti.f32, shape=7),
        lambda: ti.ndarray(ti.f64, shape=7),
        lambda: ti.ndarray(ti.i32, shape=7),
    ],
)
def test_rows_match_taichis_to_numpy(make):
    arr = make()
    rng = np.random.default_rng(1)
    full = arr.to_numpy()
    values = (rng.random(full.shape) * 1000 - 500).astype(full.dtype)
    arr.from_numpy(values)
    for n in (0, 1, 4, 7):
        rows = rows_to_numpy(arr, n)
        twin = arr.to_numpy()[:n]
        assert rows.dtype == twin.dtype and rows.shape == twin.shape and np.array_equal(rows, twin)
        assert rows.flags.c_contiguous
    rows = rows_to_numpy(arr, 7)
    rows[...] = 0  # a copy: the ndarray keeps its values
    assert np.array_equal(arr.to_numpy(), values)


def test_rows_beyond_the_array_are_refused():
    arr = ti.ndarray(ti.f32, shape=3)
    with pytest.raises(ValueError, match="4 rows asked of an array of 3"):
        rows_to_numpy(arr, 4)
    with pytest.raises(ValueError, match="-1 rows"):
        rows_to_numpy(arr, -1)


def test_a_gpu_runtime_copies_by_taichis_own_to_numpy(monkeypatch):
    """On a GPU the serial copy would run on one thread: the rows come from ``to_numpy`` there."""
    import types

    import fluidsim.host_copy as host_copy

    arr = ti.Vector.ndarray(3, ti.f32, shape=5)
    arr.from_numpy(np.arange(15, dtype=np.float32).reshape(5, 3))

    def serial(*args):
        raise AssertionError("the serial copy ran on a GPU runtime")

    monkeypatch.setattr(host_copy, "_vectors_to_numpy", serial)
    monkeypatch.setattr(ti.lang.impl, "current_cfg", lambda: types.SimpleNamespace(arch=ti.cuda))
    rows = rows_to_numpy(arr, 3)
    assert np.array_equal(rows, np.arange(9, dtype=np.float32).reshape(3, 3)) and rows.flags.c_contiguous
