"""Delentropic Scene Profile (DSP): per-image complexity and the scene profile, official values.

``delentropy``, ``glcm_entropy`` and ``pixel_entropy`` work on 8-bit greyscale arrays;
``image_complexity`` reads a file as the official code does; ``fit_profile`` fits the Beta profile;
``profile_images`` runs a whole collection (workers, cache) and ``plot_profile`` draws it. The
command line is ``claravid-dsp`` (:mod:`claravid.dsp.cli`).

Every name below is imported on first use (PEP 562): importing this package loads no torch, no
OpenCV and no file reader, so the numpy-only ``claravid.eval.analysis`` can take the profile fit
(:mod:`claravid.dsp.profile`) and the measures' names (:mod:`claravid.dsp.measures`) alone.
"""

from __future__ import annotations

import importlib
from typing import Any

# Public name -> module that defines it, imported on first access (PEP 562).
_LAZY = {
    "ComplexityCache": "claravid.dsp.cache",
    "ImageError": "claravid.dsp.collection",
    "ImageResult": "claravid.dsp.collection",
    "MeasuredImage": "claravid.dsp.collection",
    "NoImagesError": "claravid.dsp.collection",
    "ProfileRun": "claravid.dsp.collection",
    "compute_complexities": "claravid.dsp.collection",
    "compute_measures": "claravid.dsp.collection",
    "find_images": "claravid.dsp.collection",
    "load_results": "claravid.dsp.collection",
    "merge_runs": "claravid.dsp.collection",
    "profile_images": "claravid.dsp.collection",
    "compare_table": "claravid.dsp.compare",
    "METRICS": "claravid.dsp.measures",
    "ImageReadError": "claravid.dsp.metrics",
    "deldensity_counts": "claravid.dsp.metrics",
    "delentropy": "claravid.dsp.metrics",
    "glcm_entropy": "claravid.dsp.metrics",
    "gray_complexity": "claravid.dsp.metrics",
    "image_complexity": "claravid.dsp.metrics",
    "pixel_entropy": "claravid.dsp.metrics",
    "read_gray": "claravid.dsp.metrics",
    "plot_profile": "claravid.dsp.plot",
    "DegenerateProfileWarning": "claravid.dsp.profile",
    "Profile": "claravid.dsp.profile",
    "fit_profile": "claravid.dsp.profile",
    "tile_bounds": "claravid.dsp.tiles",
    "tile_complexities": "claravid.dsp.tiles",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'claravid.dsp' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
