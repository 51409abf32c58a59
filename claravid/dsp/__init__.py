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

from typing import TYPE_CHECKING

from claravid.infra.lazy import lazy_exports

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

if TYPE_CHECKING:
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
    from claravid.dsp.measures import METRICS
    from claravid.dsp.metrics import (
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
else:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
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
        },
    )
