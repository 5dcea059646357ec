"""Kernels launched with less Python per call: :func:`fast_kernel`, a drop-in for ``ti.kernel`` on the engine's per-step
kernels.

A ``ti.kernel`` call in Taichi 1.7.4 spends tens of microseconds in Python before the kernel runs: it extracts every
argument's type features, looks up the kernel's instance and dispatches each argument through a chain of type
tests. The engine launches about 14 kernels a step with up to 20 arguments each, so on the small probes of
``--quick`` (8k-10k fluid particles, 15-20 ms a step) this Python was about a tenth of a probe's time, and it runs on
one core while the thread pool's other cores wait.

:class:`FastKernel` does that work once per argument signature: the first call goes through Taichi (which compiles
the instance), and it records the instance and, per argument, how to set it. Later calls with the same signature
(the same argument kinds, array types and template values) set the arguments straight into a launch context and
launch. The kernel, its instance and its arguments are Taichi's own, so the results are the same bits; the plain
launch stays available as ``FastKernel.plain`` (the twin the tests compare with), and any argument this path does
not handle (external numpy or torch arrays, matrices, structs, argument packs, non-primitive template values,
keyword arguments) sends that signature through the plain launch. A reset runtime (``ti.reset``, a new ``ti.init``)
gives Taichi's kernel a new instance table, which drops the recorded instances.

It relies on Taichi 1.7.4's kernel internals (``Kernel.arguments``, ``ensure_compiled``, ``compiled_kernels``, the
launch context's setters); ``setup.cfg`` pins that version.
"""

from __future__ import annotations

import functools
from typing import Any

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
        self._entries: dict[tuple, tuple | None] = {}
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
            self._entries[sig] = self._record(args)
            return result
        if entry is None or entry[0] not in k.compiled_kernels:
            return self.plain(*args)
        key, setters, returns = entry
        ctx = k.compiled_kernels[key].make_launch_context()
        for setter, index, slot, width in setters:
            value = args[index]
            if setter == "ndarray":
                if value.grad is not None:
                    return self.plain(*args)
                ctx.set_arg_ndarray((slot,), value.arr)
            elif setter == "float":
                ctx.set_arg_float((slot,), float(value))
            elif setter == "int":
                ctx.set_arg_int((slot,), int(value))
            elif setter == "uint":
                ctx.set_arg_uint((slot,), int(value))
            elif setter == "vec_float":
                for c in range(width):
                    ctx.set_struct_arg_float((slot, c), float(value[c]))
            else:  # "vec_int"
                for c in range(width):
                    ctx.set_struct_arg_int((slot, c), int(value[c]))
        prog = impl.get_runtime().prog
        prog.launch_kernel(prog.compile_kernel(prog.config(), prog.get_device_caps(), k.compiled_kernels[key]), ctx)
        if returns is None:
            return None
        runtime_ops.sync()
        values = [k.construct_kernel_ret(ctx, t, (j,)) for j, t in enumerate(returns)]
        return values[0] if len(values) == 1 else values

    def _record(self, args) -> tuple | None:
        """(instance key, setters, return types) for calls like ``args``; None: launch them plainly."""
        k = self._kernel
        if k.has_print:
            return None
        setters = []
        slot = 0
        for index, (argument, value) in enumerate(zip(k.arguments, args, strict=True)):
            ann = argument.annotation
            if isinstance(ann, template):
                if not isinstance(value, _TEMPLATE_VALUES):
                    return None
                continue
            setters.append(self._setter(ann, value, index, slot))
            if setters[-1] is None:
                return None
            slot += 1
        key = k.ensure_compiled(*args)
        return key, tuple(setters), k.return_type

    @staticmethod
    def _setter(ann, value, index: int, slot: int) -> tuple | None:
        """How one argument is set: (setter, argument index, launch slot, vector width), or None."""
        if id(ann) in primitive_types.real_type_ids and isinstance(value, _SCALARS):
            return ("float", index, slot, 0)
        if id(ann) in primitive_types.integer_type_ids and isinstance(value, (bool, int, np.integer)):
            return ("int" if is_signed(cook_dtype(ann)) else "uint", index, slot, 0)
        if isinstance(ann, ndarray_type.NdarrayType) and isinstance(value, Ndarray) and value.grad is None:
            return ("ndarray", index, slot, 0)
        if isinstance(ann, MatrixType) and ann.ndim == 1 and len(value) == ann.n:
            if ann.dtype in primitive_types.real_types:
                return ("vec_float", index, slot, ann.n)
            if ann.dtype in primitive_types.integer_types and is_signed(cook_dtype(ann.dtype)):
                return ("vec_int", index, slot, ann.n)
        return None


def fast_kernel(fn) -> FastKernel:
    """``ti.kernel`` with the lean repeated launch of :class:`FastKernel`."""
    return FastKernel(ti.kernel(fn))
