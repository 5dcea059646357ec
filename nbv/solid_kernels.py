"""Taichi kernels of :mod:`nbv.solidify`: splatting Gaussians onto a lattice as log-transmittance.

The work is flattened: every (Gaussian, lattice point of its sigma box) pair is one work item, so a
few large Gaussians do not leave all but one thread idle. A work item finds its Gaussian by binary
search in the exclusive prefix sum of the box sizes.
"""

import taichi as ti


@ti.kernel
def splat_log_transmittance(
    work_start: ti.i64,
    work_count: ti.i32,
    offsets: ti.types.ndarray(dtype=ti.i64, ndim=1),
    box_lo: ti.types.ndarray(dtype=ti.i32, ndim=2),
    box_dims: ti.types.ndarray(dtype=ti.i32, ndim=2),
    means: ti.types.ndarray(dtype=ti.f64, ndim=2),
    inv_covs: ti.types.ndarray(dtype=ti.f64, ndim=3),
    opacities: ti.types.ndarray(dtype=ti.f64, ndim=1),
    lattice_min: ti.types.vector(3, ti.f64),
    spacing: ti.f64,
    max_alpha: ti.f64,
    log_transmittance: ti.types.ndarray(dtype=ti.f32, ndim=3),
):
    """Add log(1 - o_g exp(-d_g^2 / 2)) of each Gaussian to the lattice points of its sigma box.

    Args:
        work_start, work_count: the range of flattened work items of this call.
        offsets: (G + 1,) exclusive prefix sum of the box sizes (strictly increasing: empty boxes removed).
        box_lo: (G, 3) first lattice index of each box. box_dims: (G, 3) box size in lattice points.
        means: (G, 3) m. inv_covs: (G, 3, 3) inverse covariances, 1/m^2. opacities: (G,).
        lattice_min: lattice point (0, 0, 0), m. spacing: m.
        max_alpha: clamp of o exp(-d^2/2), so that the logarithm stays finite.
        log_transmittance: (X, Y, Z) accumulated sum of logs (atomic adds).
    """
    num_g = offsets.shape[0] - 1
    for t in range(work_count):
        w = work_start + ti.cast(t, ti.i64)
        lo = 0
        hi = num_g
        while hi - lo > 1:  # invariant: offsets[lo] <= w < offsets[hi]
            mid = (lo + hi) // 2
            if offsets[mid] <= w:
                lo = mid
            else:
                hi = mid
        g = lo
        local = w - offsets[g]
        nz = ti.cast(box_dims[g, 2], ti.i64)
        ny = ti.cast(box_dims[g, 1], ti.i64)
        k = ti.cast(local % nz, ti.i32) + box_lo[g, 2]
        rest = local // nz
        j = ti.cast(rest % ny, ti.i32) + box_lo[g, 1]
        i = ti.cast(rest // ny, ti.i32) + box_lo[g, 0]
        d = ti.Vector([lattice_min[0] + spacing * i - means[g, 0],
                       lattice_min[1] + spacing * j - means[g, 1],
                       lattice_min[2] + spacing * k - means[g, 2]], ti.f64)
        d2 = ti.cast(0.0, ti.f64)
        for a in ti.static(range(3)):
            for b in ti.static(range(3)):
                d2 += d[a] * inv_covs[g, a, b] * d[b]
        alpha = ti.min(opacities[g] * ti.exp(-0.5 * d2), max_alpha)
        log_transmittance[i, j, k] += ti.cast(ti.log(1.0 - alpha), ti.f32)
