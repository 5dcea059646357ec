"""The lean kernel launch (:mod:`fluidsim.launch`) against its twin, Taichi's own launch (``FastKernel.plain``):
every argument kind the engine passes gives the same bits, template values and array dtypes select their own
instances, what the lean path does not handle goes through the plain launch, a reset runtime drops the recorded
instances, and the solver's steps are the same bits on either path."""

import numpy as np
import pytest
import taichi as ti

from fluidsim.config import SolverConfig
from fluidsim.launch import FastKernel, fast_kernel
from fluidsim.scene import lattice_in_box
from fluidsim.solver import DFSPHSolver

vec3d = ti.types.vector(3, ti.f64)
ivec3 = ti.types.vector(3, ti.i32)


@fast_kernel
def mixed(
    a: ti.types.ndarray(dtype=ti.f32, ndim=1),
    v: ti.types.ndarray(ndim=1),
    scale: ti.f32,
    shift: float,
    n: ti.i32,
    origin: vec3d,
    dims: ivec3,
    power: ti.template(),
) -> tuple[ti.i32, ti.f32]:
    total = 0.0
    for i in range(n):
        a[i] = a[i] * scale + shift + ti.cast(origin[i % 3], ti.f32) * (dims[i % 3] ** power)
        v[i] = v[i] * scale
        total += a[i]
    return n * power, total


@fast_kernel
def scaled(a: ti.types.ndarray(ndim=1), factor: ti.f32):
    for i in a:
        a[i] = a[i] * factor


@fast_kernel
def extremes(a: ti.types.ndarray(ndim=1), n: ti.i32) -> tuple[ti.types.vector(2, ti.f64), ivec3, ti.u32]:
    lo, hi = 1e30, -1e30
    for i in range(n):
        ti.atomic_min(lo, ti.cast(a[i], ti.f64))
        ti.atomic_max(hi, ti.cast(a[i], ti.f64))
    return ti.Vector([lo, hi]), ti.Vector([n, -n, 2 * n]), ti.u32(n) + ti.u32(4000000000)


def _arrays(dtype=ti.f32):
    a = ti.ndarray(dtype, 7)
    a.from_numpy(np.linspace(0.5, 2.0, 7).astype(np.float32 if dtype == ti.f32 else np.float64))
    v = ti.Vector.ndarray(3, ti.f32, 7)
    v.from_numpy(np.arange(21, dtype=np.float32).reshape(7, 3) / 7)
    return a, v


def _run(call, power):
    """Three launches with changing scalars and vectors; the arrays and returns after each."""
    a, v = _arrays()
    out = []
    for k in range(3):
        ret = call(
            a, v, 1.0 + 0.1 * k, 0.25 * k, 5 + k % 2, np.array([0.5, -1.25, 2.0]) * (k + 1), (2, 3, 4 + k), power
        )
        out.append((ret, a.to_numpy().copy(), v.to_numpy().copy()))
    return out


def _same(x, y):
    for (rx, ax, vx), (ry, ay, vy) in zip(x, y, strict=True):
        assert rx == ry
        np.testing.assert_array_equal(ax, ay)
        np.testing.assert_array_equal(vx, vy)


def test_every_argument_kind_gives_the_plain_launchs_bits():
    assert isinstance(mixed, FastKernel)
    _same(_run(mixed, 2), _run(mixed.plain, 2))


def test_vector_and_unsigned_returns_come_back_as_the_plain_launchs_numbers():
    a, _ = _arrays()
    for n in (7, 3, 5):
        fast = extremes(a, n)
        vec, ivec, big = extremes.plain(a, n)
        assert fast == [tuple(vec), tuple(ivec), big]
        assert fast[0] == (0.5, float(a.to_numpy()[n - 1])) and fast[2] == n + 4000000000


def test_repeated_calls_skip_taichis_instance_lookup(monkeypatch):
    """The lean path is taken: after the first call of a signature, no call goes through ``ensure_compiled``."""
    calls = []
    kernel = mixed._kernel
    real = kernel.ensure_compiled
    monkeypatch.setattr(kernel, "ensure_compiled", lambda *a: calls.append(1) or real(*a))
    a, v = _arrays()
    mixed(a, v, 1.0, 0.0, 3, (0.0, 0.0, 0.0), (1, 1, 1), 1)  # may record (once per signature)
    before = len(calls)
    for _ in range(5):
        mixed(a, v, 1.0, 0.0, 3, (0.0, 0.0, 0.0), (1, 1, 1), 1)
    assert len(calls) == before


def test_template_values_and_array_dtypes_select_their_own_instances():
    for power in (1, 3, 1, 2):  # a signature keyed on the template's type alone would reuse power 1's instance
        _same(_run(mixed, power), _run(mixed.plain, power))
    for dtype in (ti.f32, ti.f64, ti.f32):
        a, _ = _arrays(dtype)
        b, _ = _arrays(dtype)
        scaled(a, 1.5)
        scaled.plain(b, 1.5)
        assert a.to_numpy().dtype == b.to_numpy().dtype
        np.testing.assert_array_equal(a.to_numpy(), b.to_numpy())


def test_what_the_lean_path_does_not_set_goes_through_the_plain_launch():
    host = np.linspace(0.0, 1.0, 5, dtype=np.float32)  # an external numpy array
    for _ in range(2):
        scaled(host, 2.0)
    np.testing.assert_allclose(host, np.linspace(0.0, 1.0, 5) * 4, rtol=1e-6)
    with pytest.raises(Exception, match="[Aa]rgument"):  # a wrong argument type is Taichi's error, as before
        a, _ = _arrays()
        scaled(a, "two")


def test_a_reset_runtime_drops_the_recorded_instances(taichi_runtime):
    a, _ = _arrays()
    scaled(a, 2.0)
    scaled(a, 2.0)  # recorded and launched lean
    taichi_runtime.init()  # a new runtime: the recorded instance belonged to the old one
    a, _ = _arrays()
    scaled(a, 2.0)
    scaled(a, 2.0)
    np.testing.assert_allclose(a.to_numpy(), np.linspace(0.5, 2.0, 7) * 4, rtol=1e-6)


def _steps(steps=12):
    cfg = SolverConfig(particle_radius=0.05)
    fluid = lattice_in_box([0.2, 0.3, 0.2], [0.7, 0.8, 0.7], cfg.spacing)
    wall = lattice_in_box([0.0, 0.0, 0.0], [1.0, 0.2, 1.0], cfg.spacing)
    solver = DFSPHSolver(cfg, [0, 0, 0], [1, 1.2, 1], fluid, np.tile([0.5, -1.0, 0.2], (len(fluid), 1)), wall)
    stats = [solver.step() for _ in range(steps)]
    return stats, solver.fluid.numpy("x"), solver.fluid.numpy("v")


def test_the_solvers_steps_are_the_same_bits_on_the_plain_launch(monkeypatch):
    fast = _steps()
    monkeypatch.setattr(FastKernel, "__call__", lambda self, *args: self.plain(*args))
    plain = _steps()
    assert [s.density_iterations for s in fast[0]] == [s.density_iterations for s in plain[0]]
    np.testing.assert_array_equal(fast[1], plain[1])
    np.testing.assert_array_equal(fast[2], plain[2])
