"""PEP 562 lazy re-exports, shared by the packages' ``__init__`` (standard library only).

A package lists its public names and the submodule that defines each; a name's submodule is imported on its first
use, so importing the package (or one light submodule of it) starts neither Taichi nor torch.

Example::

    __getattr__, __dir__ = lazy_exports(__name__, {"SolverConfig": "config"}, globals())
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
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
        raises AttributeError; an import error inside an existing submodule propagates unchanged.
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

    return __getattr__, __dir__
