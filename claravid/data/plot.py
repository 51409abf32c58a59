"""Pictures of data: a sample with its mask (and prediction), a sheet of samples."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from claravid.data.palettes import Palette
from claravid.infra.files import atomic_save


def displayable_image(image: Any) -> np.ndarray:
    """A sample image ([3,H,W] or H×W×3, uint8 or normalised float) as H×W×3 in [0, 1]."""
    array = np.asarray(image.detach().cpu() if hasattr(image, "detach") else image)
    if array.ndim == 3 and array.shape[0] == 3 and array.shape[-1] != 3:
        array = array.transpose(1, 2, 0)
    if array.dtype == np.uint8:
        return array.astype(np.float32) / 255.0
    # Normalised floats: stretch to the visible range, per image.
    low, high = np.percentile(array, [1, 99])
    return np.clip((array - low) / max(high - low, 1e-6), 0.0, 1.0)


def _ids(mask: Any) -> np.ndarray:
    return np.asarray(mask.detach().cpu() if hasattr(mask, "detach") else mask)


def _legend(palette: Palette, present: set[int]) -> list[Patch]:
    """Legend entries for the train ids present (ignore last)."""
    handles = [
        Patch(facecolor=palette.colors[i] / 255.0, edgecolor="k", label=name)
        for i, name in enumerate(palette.names)
        if i in present
    ]
    if palette.ignore_index in present:
        handles.append(Patch(facecolor="k", edgecolor="k", label="ignore"))
    return handles


def plot_sample(
    sample: dict[str, Any],
    palette: Palette,
    show_titles: bool = True,
    suptitle: str | None = None,
) -> Figure:
    """Image, mask in palette colours with a legend, and the prediction when present."""
    panels = [("Image", displayable_image(sample["image"]))]
    present: set[int] = set()
    for key, title in (("mask", "Mask"), ("prediction", "Prediction")):
        if key in sample:
            ids = _ids(sample[key])
            present |= set(np.unique(ids).tolist())
            panels.append((title, palette.colorize(ids)))
    fig = Figure(figsize=(4.5 * len(panels), 4.2), layout="constrained")
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for ax, (title, picture) in zip(axes, panels, strict=True):
        ax.imshow(picture, interpolation="nearest")
        ax.set_axis_off()
        if show_titles:
            ax.set_title(title)
    handles = _legend(palette, present)
    if handles:
        fig.legend(handles=handles, loc="outside right center", fontsize="small")
    if suptitle:
        fig.suptitle(suptitle)
    return fig


def save_sample_sheet(
    samples: Sequence[dict[str, Any]],
    palette: Palette,
    path: str | Path,
    titles: Sequence[str] | None = None,
) -> Path:
    """Save a grid of images (left) and their masks (right), one row per sample."""
    fig = Figure(figsize=(8.5, 3.0 * len(samples)), layout="constrained")
    axes = fig.subplots(len(samples), 2, squeeze=False)
    present: set[int] = set()
    for row, sample in enumerate(samples):
        ids = _ids(sample["mask"])
        present |= set(np.unique(ids).tolist())
        axes[row, 0].imshow(displayable_image(sample["image"]))
        axes[row, 1].imshow(palette.colorize(ids), interpolation="nearest")
        axes[row, 0].set_title(titles[row] if titles else sample.get("key", ""), fontsize="small")
        for ax in axes[row]:
            ax.set_axis_off()
    fig.legend(handles=_legend(palette, present), loc="outside right center", fontsize="small")
    return atomic_save(path, lambda tmp: fig.savefig(tmp, dpi=90))
