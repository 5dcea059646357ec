"""Rows of a Taichi ndarray copied to numpy by one launch: what a step reads on the host (a probe's fluid for the
empty-scene cache, the force's partial sums).

Taichi's ``to_numpy`` sets up a parallel copy of the whole array through its own launch. For the rows a step reads
that took about four times as long: 395 against 99 us for 10k positions and D_i, 143 against 38 us for three rows of
partial sums (measured 2026-12-06, 2-core CPU). :func:`rows_to_numpy` gives the same array as
``arr.to_numpy()[:n]`` (its twin, compared in the tests), and is that twin on a GPU, where a serial loop would run on
one thread.
"""

import numpy as np
import taichi as ti
from taichi.lang.util import to_numpy_type

from .launch import fast_kernel


@fast_kernel
def _vectors_to_numpy(n: ti.i32, src: ti.types.ndarray(ndim=1), dst: ti.types.ndarray(ndim=2)):
    ti.loop_config(serialize=True)
    for i in range(n):
        v = src[i]
        for k in ti.static(range(v.n)):
            dst[i, k] = v[k]


@fast_kernel
def _scalars_to_numpy(n: ti.i32, src: ti.types.ndarray(ndim=1), dst: ti.types.ndarray(ndim=1)):
    ti.loop_config(serialize=True)
    for i in range(n):
        dst[i] = src[i]


def rows_to_numpy(arr, n: int) -> np.ndarray:
    """``arr.to_numpy()[:n]`` of a 1-D Taichi ndarray of scalars or vectors, as a new array, by one serial launch.

    Raises:
        ValueError: ``n`` outside [0, the array's length].
    """
    if not 0 <= n <= arr.shape[0]:
        raise ValueError(f"{n} rows asked of an array of {arr.shape[0]}")
    if ti.lang.impl.current_cfg().arch not in (ti.x64, ti.arm64):  # a serial loop would run on one GPU thread
        return np.ascontiguousarray(arr.to_numpy()[:n])
    dtype = to_numpy_type(arr.dtype)
    if hasattr(arr, "n"):  # a vector ndarray
        out = np.empty((n, arr.n), dtype)
        _vectors_to_numpy(n, arr, out)
    else:
        out = np.empty(n, dtype)
        _scalars_to_numpy(n, arr, out)
    return out
