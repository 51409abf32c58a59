"""claravid: semantic segmentation and scene complexity on the ClaraVid UAV dataset.

Importing this package is light (no torch): the torch Datasets are loaded on first use.
Our import name is the official ClaraVid SDK's (PyPI ``claravid``), whose ``ClaravidDataset``
we provide as a drop-in; do not install both in one environment.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from claravid.infra.lazy import lazy_exports

__version__ = "0.2.0.dev0"

__all__ = [
    "ClaraVidSegmentation",
    "ClaravidDataset",
    "CorruptFileError",
    "DatasetNotFoundError",
    "FolderSegmentation",
    "Palette",
    "RealSegmentation",
    "UAVidSegmentation",
    "load_palette",
]

if TYPE_CHECKING:
    from claravid.data.palettes import Palette, load_palette
    from claravid.data.real_layouts import RealSegmentation
    from claravid.data.sdk import ClaravidDataset
    from claravid.data.segmentation import ClaraVidSegmentation
    from claravid.data.targets import FolderSegmentation, UAVidSegmentation
    from claravid.infra.errors import CorruptFileError, DatasetNotFoundError
else:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "ClaravidDataset": "claravid.data.sdk",
            "ClaraVidSegmentation": "claravid.data.segmentation",
            "UAVidSegmentation": "claravid.data.targets",
            "FolderSegmentation": "claravid.data.targets",
            "RealSegmentation": "claravid.data.real_layouts",
            "Palette": "claravid.data.palettes",
            "load_palette": "claravid.data.palettes",
            "DatasetNotFoundError": "claravid.infra.errors",
            "CorruptFileError": "claravid.infra.errors",
        },
    )
