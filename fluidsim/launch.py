"""Kernels launched with less Python per call: :func:`fast_kernel`, a drop-in for ``ti.kernel`` on the engine's
per-step kernels.

A ``ti.kernel`` call in Taichi 1.7.4 spends tens of microseconds in Python before the kernel runs: it extracts every
argument's type features, looks up the kernel's instance, dispatches each argument through a chain of type tests
and builds a fresh launch context. The engine launches about 14 kernels a step with up to 20 arguments each, so on
the small probes of ``--quick`` (8k-10k fluid particles, 7-10 ms a step) this was about a tenth of a probe's time,
on one core while the thread pool's other cores waited.

:class:`FastKernel` does that work once per argument signature: the first call goes through Taichi (which compiles
the instance), and it records the instance and, per argument, how to set it. Later calls with the same signature
(argument kinds, array types, template values) set the arguments straight into a fresh launch context and launch:
an empty kernel with 12 arrays and 2 scalars took ~100 us a call against Taichi's ~160-180 us (one core, 2026-12-06).
A context is not reused: Taichi's CPU launcher rewrites its array entries into raw addresses, and a second launch of
one corrupted the arrays (tried). Return values are read without building Taichi vectors: a vector comes back as a
tuple of Python numbers, on the first call too.

The kernel, its instance and its arguments are Taichi's own, so the results are the same bits. The plain launch
stays available as ``FastKernel.plain`` (the twin the tests compare with), and what this path does not handle
(external numpy or torch arrays, arrays with gradients, matrices, structs, argument packs, non-primitive template
values, keyword arguments, kernels that print) goes through the plain launch. A reset runtime (``ti.reset``, a new
``ti.init``) gives Taichi's kernel a new instance table, which drops what was recorded.

It relies on Taichi 1.7.4's kernel internals (``Kernel.arguments``, ``ensure_compiled``, ``compiled_kernels``, the
launch context's setters and getters); ``setup.cfg`` pins that version.
"""

from __future__ import annotations

import functools
import operator
from typing import Any, NamedTuple

import numpy as np
import taichi as ti
from taichi.lang import impl, runtime_ops
from taichi.lang._ndarray import Ndarray
from taichi.lang.matrix import MatrixType
from taichi.lang.util import cook_dtype
from taichi.types import ndarray_type, primitive_types, template
from taichi.types.utils import is_signed

# Template values this path keys on by value; anything else is launched plainly.
_TEMPLATE_VALUES = (bool, int, float, str, type(None), type)
_SCALARS = (bool, int, float, np.integer, np.floating)


def _signature_item(value: Any, is_template: bool) -> Any:
    """What selects a kernel instance and the argument setters: a template argument's value, an array's class,
    dtype and dimensions, a scalar's class."""
    if is_template:
        return ("t", type(value), value)
    if isinstance(value, Ndarray):
        return (type(value), value.dtype, len(value.shape), getattr(value, "n", 0), getattr(value, "m", 0))
    return type(value)


class FastKernel:
    """A ``ti.kernel`` whose repeated calls set their arguments directly (module docstring).

    Args:
        plain: the ``ti.kernel``-decorated function.
    Example:
        >>> @fast_kernel
        ... def fill(a: ti.types.ndarray(), value: ti.f32):
        ...     for i in a:
        ...         a[i] = value
    """

    def __init__(self, plain) -> None:
        functools.update_wrapper(self, plain)
        self.plain = plain
        self._kernel = plain._primal  # Taichi's Kernel object
        self._templates = tuple(isinstance(a.annotation, template) for a in self._kernel.arguments)
        self._entries: dict[tuple, _Entry | None] = {}
        self._table = None  # the Kernel's instance table the entries were recorded against

    def __call__(self, *args):
        if len(args) != len(self._templates):
            return self.plain(*args)
        k = self._kernel
        if k.compiled_kernels is not self._table:  # a reset runtime: the recorded instances are gone
            self._entries.clear()
            self._table = k.compiled_kernels
        try:
            sig = tuple(map(_signature_item, args, self._templates))
            entry = self._entries.get(sig, False)
        except TypeError:  # an unhashable template value
            return self.plain(*args)
        if entry is False:  # first call with this signature: Taichi compiles and launches, we record
            result = self.plain(*args)
            entry = self._entries[sig] = self._record(args)
            return result if entry is None else _as_returned(result, entry.returns)
        if entry is None or k.compiled_kernels.get(entry.key) is not entry.instance:
            return self.plain(*args)
        # A fresh context each launch: the CPU launcher rewrites a context's array entries into raw addresses, so a
        # context cannot be launched twice (tried: a reused context corrupted the next launch's arrays).
        ctx = entry.instance.make_launch_context()
        for index, slot in entry.arrays:
            value = args[index]
            if value.grad is not None:
                return self.plain(*args)
            ctx.set_arg_ndarray((slot,), value.arr)
        for index, slot in entry.floats:
            ctx.set_arg_float((slot,), float(args[index]))
        for index, slot in entry.ints:
            ctx.set_arg_int((slot,), operator.index(args[index]))
        for index, slot in entry.uints:
            ctx.set_arg_uint((slot,), operator.index(args[index]))
        for index, slot, width in entry.float_vectors:
            value = args[index]
            for c in range(width):
                ctx.set_struct_arg_float((slot, c), float(value[c]))
        for index, slot, width in entry.int_vectors:
            value = args[index]
            for c in range(width):
                ctx.set_struct_arg_int((slot, c), operator.index(value[c]))
        prog = impl.get_runtime().prog
        prog.launch_kernel(prog.compile_kernel(prog.config(), prog.get_device_caps(), entry.instance), ctx)
        if not entry.returns:
            return None
        runtime_ops.sync()
        values = [_read_return(ctx, j, kind, width) for j, (kind, width) in enumerate(entry.returns)]
        return values[0] if len(values) == 1 else values

    def _record(self, args) -> _Entry | None:
        """How calls like ``args`` are launched; None: plainly."""
        k = self._kernel
        if k.has_print:
            return None
        groups: dict[str, list] = {kind: [] for kind in _Entry._fields[2:8]}
        slot = 0
        for index, (argument, value) in enumerate(zip(k.arguments, args, strict=True)):
            ann = argument.annotation
            if isinstance(ann, template):
                if not isinstance(value, _TEMPLATE_VALUES):
                    return None
                continue
            setter = _setter(ann, value)
            if setter is None:
                return None
            kind, width = setter
            groups[kind].append((index, slot, width) if kind.endswith("vectors") else (index, slot))
            slot += 1
        returns = tuple(_return_kind(t) for t in (k.return_type or ()))
        if None in returns:
            return None
        key = k.ensure_compiled(*args)
        groups_in_order = (tuple(groups[kind]) for kind in _Entry._fields[2:8])
        return _Entry(key, k.compiled_kernels[key], *groups_in_order, returns)


class _Entry(NamedTuple):
    """A recorded signature: Taichi's instance key and instance, the arguments by how they are set ((argument index,
    launch slot[, vector width]) each), and each return value's (kind, vector width or 0)."""

    key: tuple
    instance: Any
    arrays: tuple
    floats: tuple
    ints: tuple
    uints: tuple
    float_vectors: tuple
    int_vectors: tuple
    returns: tuple


def _setter(ann, value) -> tuple[str, int] | None:
    """How one argument is set: (group of :class:`_Entry`, vector width or 0), or None (launched plainly)."""
    if id(ann) in primitive_types.real_type_ids and isinstance(value, _SCALARS):
        return "floats", 0
    if id(ann) in primitive_types.integer_type_ids and isinstance(value, (bool, int, np.integer)):
        return ("ints" if is_signed(cook_dtype(ann)) else "uints"), 0
    if isinstance(ann, ndarray_type.NdarrayType) and isinstance(value, Ndarray) and value.grad is None:
        return "arrays", 0
    if isinstance(ann, MatrixType) and ann.ndim == 1 and len(value) == ann.n:
        if ann.dtype in primitive_types.real_types:
            return "float_vectors", ann.n
        if ann.dtype in primitive_types.integer_types and is_signed(cook_dtype(ann.dtype)):
            return "int_vectors", ann.n
    return None


def _return_kind(ret) -> tuple[str, int] | None:
    """How one return value is read: ("float" | "int" | "uint", vector width or 0), or None (launched plainly)."""
    width = 0
    if isinstance(ret, MatrixType):
        if ret.ndim != 1:
            return None
        ret, width = ret.dtype, ret.n
    if id(ret) in primitive_types.real_type_ids or ret in primitive_types.real_types:
        return "float", width
    if id(ret) in primitive_types.integer_type_ids or ret in primitive_types.integer_types:
        return ("int" if is_signed(cook_dtype(ret)) else "uint"), width
    return None


def _read_return(ctx, j: int, kind: str, width: int):
    """Return value ``j``: a Python number, or a tuple of them for a vector."""
    get = (
        ctx.get_struct_ret_float
        if kind == "float"
        else ctx.get_struct_ret_int
        if kind == "int"
        else (ctx.get_struct_ret_uint)
    )
    if not width:
        return get((j,))
    return tuple(get((j, c)) for c in range(width))


def _as_returned(result, returns: tuple):
    """Taichi's return of the recording call in the lean path's form: a vector as a tuple of Python numbers."""
    if not returns:
        return result
    values = [result] if len(returns) == 1 else list(result)
    values = [tuple(v[c] for c in range(w)) if w else v for v, (_, w) in zip(values, returns, strict=True)]
    return values[0] if len(values) == 1 else values


def fast_kernel(fn) -> FastKernel:
    """``ti.kernel`` with the lean repeated launch of :class:`FastKernel`."""
    return FastKernel(ti.kernel(fn))
