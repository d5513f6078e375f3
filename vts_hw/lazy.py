"""A package's names given from its submodules when first asked for (PEP 562): a command that
stops at a bad input says so before the plotting and fitting libraries load."""

from __future__ import annotations

import importlib


def load(module: str, name: str):
    """``name`` of ``module``, importing the module now if it is not yet."""
    return getattr(importlib.import_module(module), name)


def exports(package: str, where: dict[str, str]):
    """A module ``__getattr__`` that gives each name of ``where`` (name -> submodule of
    ``package``) from its submodule, imported on first use."""

    def __getattr__(name: str):
        if name in where:
            return load(f"{package}.{where[name]}", name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__


__all__ = ["exports", "load"]
