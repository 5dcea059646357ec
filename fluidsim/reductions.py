"""Deterministic parallel reductions: fixed chunks summed in parallel, chunk sums added in order.

Atomic float sums depend on thread timing; a solver whose stopping test reads such a sum can take a
different number of iterations from run to run. These functions are called at the top level of a
kernel, after the loop that fills ``values``.
"""

import taichi as ti

# Chunks of the two-stage sum; enough parallel slack for a CPU, cheap to add serially.
REDUCTION_CHUNKS = 128


@ti.func
def ordered_sum(values: ti.template(), n, partial: ti.template()) -> ti.f64:
    """Sum of ``values[0:n]`` in float64, in an order independent of the thread count."""
    chunks = partial.shape[0]
    for c in range(chunks):
        lo = c * n // chunks
        hi = (c + 1) * n // chunks
        s = ti.cast(0.0, ti.f64)
        for i in range(lo, hi):
            s += ti.cast(values[i], ti.f64)
        partial[c] = s
    total = ti.cast(0.0, ti.f64)
    ti.loop_config(serialize=True)
    for c in range(chunks):
        total += partial[c]
    return total
