"""Delentropic Scene Profile (DSP): per-image complexity and the scene profile, official values.

``delentropy``, ``glcm_entropy`` and ``pixel_entropy`` work on 8-bit greyscale arrays;
``image_complexity`` reads a file as the official code does; ``fit_profile`` fits the Beta profile;
``profile_images`` runs a whole collection (workers, cache) and ``plot_profile`` draws it. The
command line is ``claravid-dsp`` (:mod:`claravid.dsp.cli`). Importing this package never imports
torch.
"""

from __future__ import annotations

from claravid.dsp.cache import ComplexityCache
from claravid.dsp.collection import (
    ImageError,
    ImageResult,
    MeasuredImage,
    NoImagesError,
    ProfileRun,
    compute_complexities,
    compute_measures,
    find_images,
    load_results,
    merge_runs,
    profile_images,
)
from claravid.dsp.compare import compare_table
from claravid.dsp.metrics import (
    METRICS,
    ImageReadError,
    deldensity_counts,
    delentropy,
    glcm_entropy,
    gray_complexity,
    image_complexity,
    pixel_entropy,
    read_gray,
)
from claravid.dsp.plot import plot_profile
from claravid.dsp.profile import DegenerateProfileWarning, Profile, fit_profile
from claravid.dsp.tiles import tile_bounds, tile_complexities

__all__ = [
    "METRICS",
    "ComplexityCache",
    "DegenerateProfileWarning",
    "ImageError",
    "ImageReadError",
    "ImageResult",
    "MeasuredImage",
    "NoImagesError",
    "Profile",
    "ProfileRun",
    "compare_table",
    "compute_complexities",
    "compute_measures",
    "deldensity_counts",
    "delentropy",
    "find_images",
    "fit_profile",
    "glcm_entropy",
    "gray_complexity",
    "image_complexity",
    "load_results",
    "merge_runs",
    "pixel_entropy",
    "plot_profile",
    "profile_images",
    "read_gray",
    "tile_bounds",
    "tile_complexities",
]
