"""PEP 562 lazy re-exports, shared by the packages' ``__init__`` (standard library only).

A package lists its public names and the submodule that defines each; a name's submodule is imported on its first
use, so importing the package (or one light submodule of it) starts neither Taichi nor torch.

A public name may share its name with the submodule that defines it (``recon.render``, the function, lives in
``recon/render.py``). Importing that submodule makes the import system bind the module to the package attribute of
that name, which would shadow the function from then on (``import recon, nbv.heatmap; recon.render`` would be
the module). The package's module class therefore refuses that one binding, so the public name always wins;
``from recon.render import ...`` and ``sys.modules["recon.render"]`` still reach the module.

Example::

    __getattr__, __dir__ = lazy_exports(__name__, {"SolverConfig": "config"}, globals())
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from types import ModuleType
from typing import Any


def lazy_exports(
    package: str, exports: Mapping[str, str], namespace: dict[str, Any]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of ``package``.

    Args:
        package: the package's ``__name__``.
        exports: public name -> the submodule (relative to ``package``) that defines it.
        namespace: the package's ``globals()``; a loaded name is cached there.
    Returns:
        (__getattr__, __dir__). A name that is not exported is tried as a submodule (``package.name``), else it
        raises AttributeError; an import error inside an existing submodule propagates unchanged. When
        ``package`` is being imported, its module's class is swapped for one that keeps an exported name from
        being shadowed by the submodule of the same name (see the module docstring).
    """

    def __getattr__(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            try:  # a submodule reached as an attribute (``nbv.heatmap``) after ``import nbv``
                return importlib.import_module(f"{package}.{name}")
            except ModuleNotFoundError as exc:
                if exc.name != f"{package}.{name}":
                    raise
                raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *exports})

    class _Package(ModuleType):
        def __setattr__(self, name: str, value: Any) -> None:
            if name in exports and isinstance(value, ModuleType) and value.__name__ == f"{package}.{name}":
                return  # the import system binding submodule ``name``: the exported name of that name wins
            super().__setattr__(name, value)

    module = sys.modules.get(package)
    if module is not None and module.__dict__ is namespace and type(module) is ModuleType:
        module.__class__ = _Package
    return __getattr__, __dir__
