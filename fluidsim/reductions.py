"""Deterministic parallel averages: fixed-point sums that do not depend on the order of the additions.

Atomic float sums depend on thread timing; a solver whose stopping test reads such a sum can take a
different number of iterations from run to run. Here every value (>= 0) becomes a whole number of quanta
(rounded to the nearest) and the integers are added; integer addition is exact and associative, so the
sum, and the average, are the same bit for bit on any number of threads, and the producing pass sums as
it goes: Taichi keeps one integer per thread and adds them at the end, with no extra pass and no
thread-pool wake-up of its own (a separate pass over fixed chunks cost about 50 us per solver iteration).

The quantum is the solver's tolerance / 2^FIXED_POINT_BITS, so an average is exact to within
2^-21 of the tolerance. A value is representable up to ``2^62 / n`` quanta (n values cannot
overflow 2^62): tolerance x 2^42 / n, e.g. 7.5e7 tolerances at n = 58k particles or 4.4e5 at 10M. A value
past that, or NaN / Inf, makes the average +Inf (the solve then reads a huge error, never a small one).
:func:`fixed_point_average_np` is the numpy twin.
"""

import numpy as np
import taichi as ti

FIXED_POINT_BITS = 20
_SUM_LIMIT = 1 << 62


def inverse_quantum(tolerance: float) -> float:
    """Quanta per unit of the averaged quantity for a solver tolerance (> 0)."""
    return float(2**FIXED_POINT_BITS) / float(tolerance)


@ti.func
def quantum_cap(n) -> ti.f64:
    """The largest number of quanta one of ``n`` values may hold (their sum stays below 2^62)."""
    return ti.cast(ti.i64(_SUM_LIMIT) // ti.max(ti.cast(n, ti.i64), 1), ti.f64)


@ti.func
def to_quanta(value, inv_quantum, cap):
    """(quanta, 0) for a value >= 0 (rounded to the nearest quantum), or (0, 1) past ``cap`` quanta or
    non-finite. Add both parts into kernel-scope i64 sums inside the producing loop."""
    q = ti.cast(value, ti.f64) * inv_quantum
    quanta = ti.i64(0)
    over = ti.i64(1)
    if q < cap:  # False for NaN
        quanta = ti.cast(q + 0.5, ti.i64)
        over = ti.i64(0)
    return quanta, over


@ti.func
def quanta_average(total, over, n, inv_quantum) -> ti.f64:
    """The average of n values from their summed quanta; +Inf when one of them was out of range."""
    avg = ti.cast(total, ti.f64) / inv_quantum / ti.max(n, 1)
    if over > 0:
        avg = ti.math.inf
    return avg


def fixed_point_average_np(values: np.ndarray, inv_quantum: float) -> float:
    """Numpy twin of the fixed-point average (the same float operations, so the same bits)."""
    v = np.asarray(values).astype(np.float64)
    n = len(v)
    q = v * inv_quantum
    if not np.all(q < float(_SUM_LIMIT // max(n, 1))):
        return float("inf")
    total = int((q + 0.5).astype(np.int64).sum())
    return float(np.float64(total) / inv_quantum / max(n, 1))
