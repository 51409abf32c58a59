"""Public names of a package imported on first use (PEP 562), so importing the package stays light.

A package lists its public names twice, once for each reader::

    __all__ = ["Palette", "load_palette"]

    if TYPE_CHECKING:  # what type checkers and IDEs read
        from claravid.data.palettes import Palette, load_palette
    else:  # what runs: nothing is imported until a name is asked for
        __getattr__, __dir__ = lazy_exports(__name__, {
            "Palette": "claravid.data.palettes",
            "load_palette": "claravid.data.palettes",
        })

The two must agree: a test reads every package that uses this and compares them.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(
    package: str, exports: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Build a package's module-level ``__getattr__`` and ``__dir__`` for names loaded on use.

    Args:
        package: the package's ``__name__``.
        exports: each public name and the module that defines it under that name.

    Returns:
        ``(__getattr__, __dir__)``: ``__getattr__(name)`` imports the name's module and returns
        its attribute (``AttributeError`` for any other name); ``__dir__()`` lists the package's
        own globals and every exported name.
    """
    table = dict(exports)

    def __getattr__(name: str) -> Any:
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(module), name)

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[package]), *table})

    return __getattr__, __dir__
