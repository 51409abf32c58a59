"""Ground sampling distance (GSD, metres per pixel) of ClaraVid frames, as a model learns them.

A frame's GSD is taken at its principal point, the image centre: the planar depth there divided
by the focal length in pixels at the frame's stored size (``claravid.io.layout``'s intrinsics,
scaled with the frame). The principal point of a frame of even size lies on the corner shared by
the four central pixels, so the depth there is their mean (bilinear interpolation at that point).
An oblique view spans a range of GSDs within one frame; the centre is its middle.

A training run records the median over its training frames (evenly spaced ones, at most
:data:`MAX_FRAMES`: a depth PNG is decoded whole, and the median of a few dozen frames of three
altitudes is already stable). Training reads the frames at their stored resolution, so that is
the model's scale; evaluation's ``scale`` resizes after.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from claravid.io import modalities
from claravid.io.layout import MISSIONS, frame_file, scaled_intrinsics

#: At most this many frames are read for a run's median.
MAX_FRAMES = 64


def centre_depth(depth: np.ndarray) -> float:
    """Planar depth (metres) at the image centre: the mean of the 1, 2 or 4 pixels that touch
    it (one for odd sides, two for even)."""
    h, w = depth.shape
    rows = [h // 2] if h % 2 else [h // 2 - 1, h // 2]
    cols = [w // 2] if w % 2 else [w // 2 - 1, w // 2]
    return float(np.mean(depth[np.ix_(rows, cols)], dtype=np.float64))


def frame_gsd(depth: np.ndarray) -> float:
    """GSD (metres per pixel) at the centre of a ClaraVid frame whose depth map is ``depth``
    (metres, at the frame's stored size)."""
    h, w = depth.shape
    fx = scaled_intrinsics((w, h))[0, 0]
    return centre_depth(depth) / fx


def median_gsd(depth_paths: Sequence[str | Path], limit: int = MAX_FRAMES) -> float | None:
    """Median centre GSD over evenly spaced frames (at most ``limit``); None without frames or
    when no frame has a finite, positive depth at its centre."""
    if not depth_paths:
        return None
    picks = np.unique(np.linspace(0, len(depth_paths) - 1, min(limit, len(depth_paths))).round())
    values = [frame_gsd(modalities.read_depth(depth_paths[int(i)])) for i in picks]
    values = [v for v in values if math.isfinite(v) and v > 0]
    return float(np.median(values)) if values else None


def gsd_record(
    value: float | None, source: str, frames: int | None = None
) -> dict[str, Any] | None:
    """What a checkpoint stores: ``{"metres_per_pixel", "source"[, "frames"]}``; None when the
    GSD is unknown."""
    if value is None:
        return None
    record: dict[str, Any] = {"metres_per_pixel": float(value), "source": source}
    if frames is not None:
        record["frames"] = int(frames)
    return record


def claravid_gsd(
    root: str | Path, frames: Sequence[Any], limit: int = MAX_FRAMES
) -> dict[str, Any] | None:
    """The GSD record of ClaraVid ``frames`` (``claravid.data.index.Frame``) under ``root``: the
    median centre GSD of their depth maps; None when none of their depth PNGs is on disk."""
    paths = [
        frame_file(Path(root) / MISSIONS[f.mission], f.viewpoint, f.stem, "depth") for f in frames
    ]
    present = [p for p in paths if p.is_file()]
    value = median_gsd(present, limit)
    source = "ClaraVid depth at the frame centre / fx, median over training frames"
    return gsd_record(value, source, min(limit, len(present)))
