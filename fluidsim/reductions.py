"""Deterministic parallel reductions: fixed chunks summed in parallel, chunk sums added in order.

Atomic float sums depend on thread timing; a solver whose stopping test reads such a sum can take a
different number of iterations from run to run. These functions are called at the top level of a
kernel, after the loop that fills ``values``.
"""

import taichi as ti

# Chunks of the two-stage sum; enough parallel slack for a CPU, cheap to add serially.
REDUCTION_CHUNKS = 128


@ti.func
def chunk_bounds(c, n, chunks):
    """Items [lo, hi) of chunk c of ``chunks`` over n items (the partition every ordered sum uses)."""
    return c * n // chunks, (c + 1) * n // chunks


@ti.func
def ordered_total(partial: ti.template()) -> ti.f64:
    """The chunk sums added in chunk order, on one thread (call at the top level of a kernel)."""
    total = ti.cast(0.0, ti.f64)
    ti.loop_config(serialize=True)
    for c in range(partial.shape[0]):
        total += partial[c]
    return total


@ti.func
def ordered_sum(values: ti.template(), n, partial: ti.template()) -> ti.f64:
    """Sum of ``values[0:n]`` in float64, in an order independent of the thread count.

    (Summing inside the producing pass, chunk by chunk, saves a parallel loop but made the density error
    pass about twice as slow on the bench scene: the per-particle loop then runs inside a chunk loop.)
    """
    chunks = partial.shape[0]
    for c in range(chunks):
        lo, hi = chunk_bounds(c, n, chunks)
        s = ti.cast(0.0, ti.f64)
        for i in range(lo, hi):
            s += ti.cast(values[i], ti.f64)
        partial[c] = s
    return ordered_total(partial)
