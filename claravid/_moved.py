"""The module paths of before ``claravid/`` was grouped into ``infra/``, ``io/`` and ``data/``.

They stay importable for code and pickles written against them: ``import claravid.segmentation``
imports ``claravid.data.segmentation`` and registers that same module object under the old name
as well. New code and the documentation use the new paths (except ``claravid.transforms``, the
README's short name for ``claravid.data.transforms``).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
from types import ModuleType

#: Old module path -> where the module lives now.
MOVED: dict[str, str] = {
    "claravid.blocks": "claravid.data.blocks",
    "claravid.cache_cli": "claravid.data.cache_cli",
    "claravid.cachedir": "claravid.infra.cachedir",
    "claravid.cli": "claravid.infra.cli",
    "claravid.demo": "claravid.synth.demo",
    "claravid.distributed": "claravid.infra.distributed",
    "claravid.errors": "claravid.infra.errors",
    "claravid.index": "claravid.data.index",
    "claravid.jpeg_region": "claravid.io.jpeg_region",
    "claravid.label_cache": "claravid.data.label_cache",
    "claravid.label_tiff": "claravid.io.label_tiff",
    "claravid.labels": "claravid.io.labels",
    "claravid.layout": "claravid.io.layout",
    "claravid.masks": "claravid.data.masks",
    "claravid.modalities": "claravid.io.modalities",
    "claravid.palettes": "claravid.data.palettes",
    "claravid.plot": "claravid.data.plot",
    "claravid.precision": "claravid.infra.precision",
    "claravid.resources": "claravid.infra.resources",
    "claravid.samples": "claravid.data.samples",
    "claravid.sdk": "claravid.data.sdk",
    "claravid.segmentation": "claravid.data.segmentation",
    "claravid.splits": "claravid.data.splits",
    "claravid.targets": "claravid.data.targets",
    "claravid.transforms": "claravid.data.transforms",
    "claravid.yamlfile": "claravid.io.yamlfile",
}


class _Alias(importlib.abc.Loader):
    """Loads an old path as the module at its new path (one module object, two names)."""

    def __init__(self, target: str) -> None:
        self.target = target

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        return importlib.import_module(self.target)

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the target module was executed when it was imported."""


class MovedModuleFinder(importlib.abc.MetaPathFinder):
    """Finds the old paths of `MOVED`; placed last on ``sys.meta_path``."""

    def find_spec(self, fullname: str, path: object = None, target: object = None):
        new = MOVED.get(fullname)
        if new is None:
            return None
        return importlib.util.spec_from_loader(fullname, _Alias(new))
