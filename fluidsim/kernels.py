"""Cubic spline smoothing kernel (Monaghan 1992) in 3-D, with support radius ``h``.

This is the kernel of SPlisHSPlasH's ``CubicKernel`` and of the paper's divergence estimator (Eq. 1):
with ``q = |r| / h`` and ``k = 8 / (pi h^3)``,

    W(r, h) = k (6 q^3 - 6 q^2 + 1)   for 0 <= q <= 1/2
            = k 2 (1 - q)^3           for 1/2 < q <= 1
            = 0                       otherwise,

and its gradient with respect to the first point, ``grad W(r, h) = W'(|r|) r / |r|``.

Each Taichi function has a numpy twin of the same name with suffix ``_np``; tests compare the two and
check the mathematics (unit integral, zero gradient sum in a full neighbourhood, compact support).
"""

import math

import numpy as np
import taichi as ti


@ti.func
def cubic_w(r_norm, h):
    """W(|r|, h) of the cubic spline; ``r_norm`` >= 0 in metres, ``h`` the support radius."""
    q = r_norm / h
    k = 8.0 / (math.pi * h * h * h)
    w = 0.0 * q
    if q <= 1.0:
        if q <= 0.5:
            w = k * (6.0 * q * q * q - 6.0 * q * q + 1.0)
        else:
            w = k * 2.0 * (1.0 - q) * (1.0 - q) * (1.0 - q)
    return w


@ti.func
def cubic_grad_coef(r_norm, h):
    """W'(|r|, h) / |r| (1/m^5): ``grad W(r, h) = cubic_grad_coef(|r|, h) r``; zero at r = 0 and |r| > h."""
    q = r_norm / h
    c = 0.0 * q
    if r_norm > 1.0e-9 * h and q <= 1.0:
        l = 48.0 / (math.pi * h * h * h)
        if q <= 0.5:
            c = l * q * (3.0 * q - 2.0) / (r_norm * h)
        else:
            factor = 1.0 - q
            c = -l * factor * factor / (r_norm * h)
    return c


@ti.func
def cubic_grad_w(r, h):
    """grad_i W(x_i - x_j, h) for ``r = x_i - x_j`` (a 3-vector, metres); zero at r = 0 and |r| > h."""
    return cubic_grad_coef(r.norm(), h) * r


# Samples of the kernel table over [0, h] (see cubic_table_np); linear interpolation between them is within
# 4e-7 of the exact W and cubic_grad_coef, relative to their largest magnitude.
CUBIC_TABLE_SIZE = 2048


@ti.func
def cubic_from_table(r_norm, scale, table: ti.template()):
    """(W(|r|, h), cubic_grad_coef(|r|, h)) by linear interpolation in :func:`cubic_table_np`'s ``table``.

    ``scale`` = table size / h; ``r_norm`` in [0, h]. No division and no branch on the spline piece,
    which is what the neighbourhood pass spends most of its kernel time on otherwise.
    """
    u = r_norm * scale
    k = ti.cast(u, ti.i32)
    t = u - k
    a = table[k]
    b = table[k + 1]
    return a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])


def cubic_w_np(r_norm: np.ndarray, h: float) -> np.ndarray:
    """Numpy twin of :func:`cubic_w`.

    Args:
        r_norm: distances [...], metres.
        h: support radius, metres.
    Returns:
        W values [...], 1/m^3.
    Example:
        >>> float(cubic_w_np(np.array(0.0), 1.0)) == 8.0 / np.pi
        True
    """
    q = np.asarray(r_norm, dtype=np.float64) / h
    k = 8.0 / (np.pi * h**3)
    inner = k * (6.0 * q**3 - 6.0 * q**2 + 1.0)
    outer = k * 2.0 * (1.0 - q) ** 3
    return np.where(q <= 0.5, inner, np.where(q <= 1.0, outer, 0.0))


def cubic_grad_w_np(r: np.ndarray, h: float) -> np.ndarray:
    """Numpy twin of :func:`cubic_grad_w`.

    Args:
        r: difference vectors x_i - x_j [..., 3], metres.
        h: support radius, metres.
    Returns:
        gradients [..., 3], 1/m^4.
    Example:
        >>> cubic_grad_w_np(np.zeros(3), 1.0).tolist()
        [0.0, 0.0, 0.0]
    """
    r = np.asarray(r, dtype=np.float64)
    r_norm = np.linalg.norm(r, axis=-1)
    q = r_norm / h
    l = 48.0 / (np.pi * h**3)
    dwdq = np.where(q <= 0.5, l * q * (3.0 * q - 2.0), np.where(q <= 1.0, -l * (1.0 - q) ** 2, 0.0))
    valid = r_norm > 1.0e-9 * h
    scale = np.where(valid, dwdq / np.where(valid, r_norm * h, 1.0), 0.0)
    return r * scale[..., None]


def cubic_table_np(h: float, size: int = CUBIC_TABLE_SIZE) -> np.ndarray:
    """Table of (W, cubic_grad_coef) at r_k = k h / size, k = 0..size, plus a padding row (zeros, as at r = h).

    Sampled in r (not r^2): on the inner piece cubic_grad_coef is linear in r, and it tends to -2 l / h^2
    (l = 48 / (pi h^3)) at r -> 0, which the table holds at k = 0.

    Args:
        h: support radius, m. size: samples over [0, h).
    Returns:
        (size + 2, 2) float64: W in 1/m^3, the coefficient in 1/m^5.
    Example:
        >>> t = cubic_table_np(1.0, 4)
        >>> t.shape, float(t[0, 0]) == 8.0 / np.pi, float(t[4, 0]) == float(t[5, 1]) == 0.0
        ((6, 2), True, True)
    """
    r = np.arange(size + 1) * (h / size)
    table = np.zeros((size + 2, 2))
    table[: size + 1, 0] = cubic_w_np(r, h)
    rr = r[1:, None] * np.array([[1.0, 0.0, 0.0]])
    table[1 : size + 1, 1] = cubic_grad_w_np(rr, h)[:, 0] / r[1:]
    table[0, 1] = -2.0 * 48.0 / (np.pi * h**3) / h**2
    return table


def cubic_from_table_np(r_norm: np.ndarray, h: float, table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Numpy twin of :func:`cubic_from_table` (``r_norm`` in [0, h])."""
    size = table.shape[0] - 2
    u = np.asarray(r_norm, dtype=np.float64) * (size / h)
    k = np.floor(u).astype(np.int64)
    t = u - k
    a, b = table[k], table[k + 1]
    return a[..., 0] + t * (b[..., 0] - a[..., 0]), a[..., 1] + t * (b[..., 1] - a[..., 1])
