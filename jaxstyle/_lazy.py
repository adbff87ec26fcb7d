"""Lazy attribute loading for jaxstyle's packages (PEP 562), so ``import jaxstyle`` stays light.

``import jaxstyle`` loads no JAX, plotting or rendering library: each public name is imported from its
module the first time it is used.
"""

from __future__ import annotations

import importlib
from typing import Callable, Iterable, Mapping


def lazy_module(package: str, submodules: Iterable[str], names: Mapping[str, str] | None = None
                ) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package``: its ``submodules`` and ``names`` (name -> module
    relative to ``package``) load on first access."""
    submodules = frozenset(submodules)
    names = dict(names or {})

    def __getattr__(name: str):
        if name in submodules:
            return importlib.import_module(f"{package}.{name}")
        if name in names:
            value = getattr(importlib.import_module(f"{package}.{names[name]}"), name)
            globals_of(package)[name] = value
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(globals_of(package)) | submodules | set(names))

    return __getattr__, __dir__


def globals_of(package: str) -> dict:
    import sys

    return vars(sys.modules[package])
