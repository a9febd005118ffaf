"""Lazy public namespaces (PEP 562): a package lists ``{private module: public names}`` and the
names are imported on first use, so importing the package itself costs nothing (no JAX)."""

from __future__ import annotations

import importlib


def lazy_exports(
    package: str, namespace: dict, exports: dict[str, tuple[str, ...]], subpackages=()
):
    """``(__getattr__, __dir__, __all__)`` for ``package`` whose globals are ``namespace``."""
    where = {name: mod for mod, names in exports.items() for name in names}
    public = sorted([*where, *subpackages])

    def __getattr__(name: str):
        if name in where:
            value = getattr(importlib.import_module(f".{where[name]}", package), name)
        elif name in subpackages:
            value = importlib.import_module(f".{name}", package)
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        namespace[name] = value  # later look-ups skip __getattr__
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(public))

    return __getattr__, __dir__, public
