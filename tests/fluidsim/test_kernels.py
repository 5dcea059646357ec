"""The cubic spline kernel: unit integral, zero gradient sum, compact support, Taichi == numpy twin."""

import numpy as np
import taichi as ti

from fluidsim.kernels import (
    CUBIC_TABLE_SIZE,
    cubic_from_table,
    cubic_from_table_np,
    cubic_grad_w,
    cubic_grad_w_np,
    cubic_table_np,
    cubic_w,
    cubic_w_np,
)


def test_kernel_integrates_to_one():
    h = 0.1
    n = 81
    ax = (np.arange(n) - (n - 1) / 2) * (2.2 * h / n)
    pts = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    integral = cubic_w_np(np.linalg.norm(pts, axis=1), h).sum() * (2.2 * h / n) ** 3
    assert abs(integral - 1.0) < 2e-3


def test_compact_support_and_positivity():
    h = 0.2
    r = np.linspace(0, 2 * h, 401)
    w = cubic_w_np(r, h)
    assert np.all(w[r > h] == 0.0)
    assert np.all(w[r < h] > 0.0)
    assert np.all(np.diff(w[r <= h]) <= 0)


def test_gradient_sums_to_zero_in_full_neighbourhood():
    spacing, h = 0.05, 0.1
    ax = np.arange(-3, 4) * spacing
    pts = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1).reshape(-1, 3)
    offset = np.array([0.013, -0.007, 0.004])  # not on a lattice node: symmetry alone can't zero it
    g = cubic_grad_w_np(offset - pts, h).sum(0)
    scale = np.abs(cubic_grad_w_np(offset - pts, h)).sum()
    assert np.linalg.norm(g) < 0.03 * scale


def test_gradient_matches_finite_difference_of_w():
    h = 0.1
    rng = np.random.default_rng(0)
    for _ in range(50):
        r = rng.uniform(-h, h, 3)
        if not 0.05 * h < np.linalg.norm(r) < 0.95 * h:
            continue
        eps = 1e-7
        fd = np.array(
            [
                (cubic_w_np(np.linalg.norm(r + eps * e), h) - cubic_w_np(np.linalg.norm(r - eps * e), h)) / (2 * eps)
                for e in np.eye(3)
            ]
        )
        np.testing.assert_allclose(cubic_grad_w_np(r, h), fd, rtol=1e-5, atol=1e-3)


@ti.kernel
def _eval(
    rs: ti.types.ndarray(dtype=ti.math.vec3, ndim=1),
    h: ti.f32,
    w: ti.types.ndarray(dtype=ti.f32, ndim=1),
    g: ti.types.ndarray(dtype=ti.math.vec3, ndim=1),
):
    for i in range(rs.shape[0]):
        w[i] = cubic_w(rs[i].norm(), h)
        g[i] = cubic_grad_w(rs[i], h)


def test_taichi_kernel_matches_numpy_twin():
    h = 0.1
    rs = np.random.default_rng(1).uniform(-0.12, 0.12, (500, 3)).astype(np.float32)
    rs[0] = 0.0
    a = ti.Vector.ndarray(3, ti.f32, shape=500)
    a.from_numpy(rs)
    w = ti.ndarray(ti.f32, shape=500)
    g = ti.Vector.ndarray(3, ti.f32, shape=500)
    _eval(a, h, w, g)
    np.testing.assert_allclose(w.to_numpy(), cubic_w_np(np.linalg.norm(rs, axis=1), h), rtol=1e-4, atol=1e-2)
    np.testing.assert_allclose(g.to_numpy(), cubic_grad_w_np(rs, h), rtol=1e-4, atol=1e-1)


def test_kernel_table_interpolates_the_spline():
    """The neighbourhood pass's table: within 4e-7 of W and of the gradient coefficient (relative to their
    largest magnitude) over [0, h], including r -> 0 and both sides of q = 1/2; Taichi equals the numpy twin."""
    h = 0.1
    table = cubic_table_np(h)
    rng = np.random.default_rng(2)
    r = np.concatenate([rng.uniform(0.0, h, 20000), [0.0, 1e-9, 0.5 * h, 0.5 * h + 1e-7, h - 1e-9]])
    w, c = cubic_from_table_np(r, h, table)
    w_exact = cubic_w_np(r, h)
    nz = r > 0
    c_exact = np.full_like(r, table[0, 1])  # the r -> 0 limit, -2 l / h^2
    c_exact[nz] = cubic_grad_w_np(r[nz, None] * np.array([[1.0, 0.0, 0.0]]), h)[:, 0] / r[nz]
    assert np.abs(w - w_exact).max() <= 4e-7 * np.abs(w_exact).max()
    assert np.abs(c - c_exact).max() <= 4e-7 * np.abs(c_exact).max()
    # a 4x coarser table is measurably worse: the bound above is the table's, not the test's slack
    w4, c4 = cubic_from_table_np(r, h, cubic_table_np(h, CUBIC_TABLE_SIZE // 4))
    assert np.abs(c4 - c_exact).max() > 4e-7 * np.abs(c_exact).max()

    ti_table = ti.Vector.ndarray(2, ti.f64, shape=len(table))
    ti_table.from_numpy(table)
    rs = ti.ndarray(ti.f64, shape=len(r))
    rs.from_numpy(r)
    out = ti.Vector.ndarray(2, ti.f64, shape=len(r))
    _eval_table(rs, (len(table) - 2) / h, ti_table, out)
    np.testing.assert_allclose(out.to_numpy()[:, 0], w, rtol=1e-5, atol=1e-6 * np.abs(w).max())
    np.testing.assert_allclose(out.to_numpy()[:, 1], c, rtol=1e-5, atol=1e-6 * np.abs(c).max())


@ti.kernel
def _eval_table(
    rs: ti.types.ndarray(dtype=ti.f64, ndim=1),
    scale: ti.f64,
    table: ti.types.ndarray(dtype=ti.types.vector(2, ti.f64), ndim=1),
    out: ti.types.ndarray(dtype=ti.types.vector(2, ti.f64), ndim=1),
):
    for i in range(rs.shape[0]):
        w, c = cubic_from_table(rs[i], scale, table)
        out[i] = ti.Vector([w, c])
