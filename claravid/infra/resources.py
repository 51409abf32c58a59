"""The YAML files shipped with the package: palettes and named experiment configs.

They live in the repository's top-level ``configs/`` folder, which is installed as the package
``claravid.configs`` (see ``pyproject.toml``), so an editable install and a wheel installed
outside the checkout read the same files through ``importlib.resources``.
"""

from __future__ import annotations

import sys
from importlib import resources
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # only annotations name it; its module moved in Python 3.11
    if sys.version_info >= (3, 11):
        from importlib.resources.abc import Traversable
    else:
        from importlib.abc import Traversable

PACKAGE = "claravid.configs"


def shipped_dir(subfolder: str = "") -> Traversable:
    """The shipped configs folder, or one of its subfolders (``"palettes"``)."""
    root = resources.files(PACKAGE)
    return root / subfolder if subfolder else root


def shipped_names(subfolder: str = "") -> list[str]:
    """Stems of the ``*.yaml`` files shipped in ``subfolder`` (sorted)."""
    folder = shipped_dir(subfolder)
    if not folder.is_dir():
        return []
    return sorted(
        entry.name.rsplit(".", 1)[0]
        for entry in folder.iterdir()
        if entry.is_file() and entry.name.endswith(".yaml")
    )


def shipped_file(name: str, subfolder: str = "") -> Traversable | None:
    """The shipped ``<subfolder>/<name>.yaml``, or None when there is no such file."""
    entry = shipped_dir(subfolder) / f"{name}.yaml"
    return entry if entry.is_file() else None
