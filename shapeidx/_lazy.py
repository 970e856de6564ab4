"""Lazy attributes for package ``__init__`` modules (PEP 562), as scikit-image does.

``import shapeidx`` must stay cheap: the command line starts in a fraction of a second and a
store can be opened without loading scipy, Embree or OpenCASCADE. A package lists where each
public name lives; the module is imported the first time the name is used.
"""

from __future__ import annotations

import importlib


def attach(package: str, names: dict[str, str]):
    """``__getattr__`` and ``__dir__`` for ``package``: ``names`` maps a name to its submodule."""

    def __getattr__(name: str):
        try:
            module = names[name]
        except KeyError:
            raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        value = getattr(importlib.import_module(module, package), name)
        globals_of_package = importlib.import_module(package).__dict__
        globals_of_package[name] = value  # later lookups skip __getattr__
        return value

    def __dir__():
        return sorted(set(importlib.import_module(package).__dict__) | set(names))

    return __getattr__, __dir__
