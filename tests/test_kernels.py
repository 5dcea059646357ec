"""The cubic spline kernel: unit integral, zero gradient sum, compact support, Taichi == numpy twin."""

import numpy as np
import taichi as ti

from fluidsim.kernels import cubic_grad_w, cubic_grad_w_np, cubic_w, cubic_w_np


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
        fd = np.array([(cubic_w_np(np.linalg.norm(r + eps * e), h) - cubic_w_np(np.linalg.norm(r - eps * e), h))
                       / (2 * eps) for e in np.eye(3)])
        np.testing.assert_allclose(cubic_grad_w_np(r, h), fd, rtol=1e-5, atol=1e-3)


@ti.kernel
def _eval(rs: ti.types.ndarray(dtype=ti.math.vec3, ndim=1), h: ti.f32,
          w: ti.types.ndarray(dtype=ti.f32, ndim=1), g: ti.types.ndarray(dtype=ti.math.vec3, ndim=1)):
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
