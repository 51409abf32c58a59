"""claravid: semantic segmentation and scene complexity on the ClaraVid UAV dataset.

Importing this package is light (no torch): the torch Datasets are loaded on first use.
Our import name is the official ClaraVid SDK's (PyPI ``claravid``), whose ``ClaravidDataset``
we provide as a drop-in; do not install both in one environment.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.2.0.dev0"

# Public name -> module that defines it, imported on first access (PEP 562).
_LAZY = {
    "ClaravidDataset": "claravid.data.sdk",
    "ClaraVidSegmentation": "claravid.data.segmentation",
    "UAVidSegmentation": "claravid.data.targets",
    "FolderSegmentation": "claravid.data.targets",
    "Palette": "claravid.data.palettes",
    "load_palette": "claravid.data.palettes",
    "DatasetNotFoundError": "claravid.infra.errors",
    "CorruptFileError": "claravid.infra.errors",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'claravid' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
