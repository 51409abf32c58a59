"""The sample dict that every dataset hands out, and the type of the transforms over it.

A sample is ``{"image": uint8 [3,H,W], "mask": int64 [H,W], "path": str, "key": str, ...}``
(``mask`` absent for unlabelled images; uint8 with ``eval_transforms`` and in datasets made
with ``mask_dtype=torch.uint8``, as evaluation makes them). A transform takes and returns the
whole dict (see ``claravid.data.transforms``); datasets cast ``mask`` to the dtype they or the
transforms ask for after it (int64 by default), so transforms may hand back uint8 masks
(albumentations warps those exactly). :func:`normalise` makes a model's input
of uint8 images where the model runs (training crops and evaluation frames travel as uint8).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

Sample = dict[str, Any]
#: What every dataset's ``transforms`` argument takes: a sample dict in, a sample dict out.
Transform = Callable[[Sample], Sample]


def image_tensor(rgb: np.ndarray) -> torch.Tensor:
    """An H×W×3 uint8 array as a [3,H,W] tensor view (transforms crop it without a copy)."""
    return torch.from_numpy(rgb).permute(2, 0, 1)


def finish_sample(
    sample: Sample, transforms: Transform | None, mask_dtype: torch.dtype | None = None
) -> Sample:
    """Apply the transforms, then give the mask (if any) ``mask_dtype``; None: the dtype the
    transforms ask for (their ``mask_dtype``: uint8 for ``eval_transforms``), else int64, for
    a loss. Evaluation keeps uint8 until the device (a 12-Mpixel int64 mask is 96 MB, and
    making it costs more than reading the labels)."""
    if transforms is not None:
        sample = transforms(sample)
    if mask_dtype is None:
        mask_dtype = getattr(transforms, "mask_dtype", None) or torch.int64
    if "mask" in sample:
        sample["mask"] = torch.as_tensor(sample["mask"]).to(mask_dtype)
    return sample


def normalise(image: torch.Tensor, mean: Sequence[float], std: Sequence[float]) -> torch.Tensor:
    """uint8 images [..., 3, H, W] as a model's float32 input, ``(image / 255 - mean) / std``
    per channel, computed on the images' device: a batch travels there as uint8, a quarter of
    the bytes of float32.

    A float image is taken as normalised already and returned as it is, when every value lies
    within what this normalisation gives for pixels 0..255 (per channel); otherwise it is refused:
    a float image of 0..255 pixels would reach the model un-normalised, silently.

    Raises:
        ValueError: a float image with a value outside the normalised range of its channel (or
            NaN), naming the channel, the value and the range.
    """
    if image.is_floating_point():
        check_normalised(image, mean, std)
        return image
    mean_ = torch.tensor(mean, dtype=torch.float32, device=image.device).view(3, 1, 1)
    std_ = torch.tensor(std, dtype=torch.float32, device=image.device).view(3, 1, 1)
    return (image.to(torch.float32) / 255.0 - mean_) / std_


#: Slack on the normalised range: float rounding of ``(x / 255 - mean) / std``, not augmentations
#: (those run on the pixels, before the normalisation).
_SLACK = 1e-3


def check_normalised(image: torch.Tensor, mean: Sequence[float], std: Sequence[float]) -> None:
    """Raise unless every value of the float images [..., 3, H, W] lies within
    ``[(0 - mean) / std, (1 - mean) / std]`` of its channel (see :func:`normalise`)."""
    if image.ndim < 3 or image.shape[-3] != 3:
        raise ValueError(f"expected images [..., 3, H, W], got shape {tuple(image.shape)}")
    flat = image.detach().movedim(-3, 0).reshape(3, -1)
    if flat.shape[1] == 0:
        return
    low, high = flat.amin(dim=1).tolist(), flat.amax(dim=1).tolist()
    for c in range(3):
        lo, hi = (0.0 - mean[c]) / std[c], (1.0 - mean[c]) / std[c]
        lo, hi = min(lo, hi), max(lo, hi)  # a negative std flips them
        # `not (a <= b)` is also true for NaN.
        if not (lo - _SLACK <= low[c] and high[c] <= hi + _SLACK):
            raise ValueError(
                f"a float image reached normalise with channel {c} values in "
                f"[{low[c]:.4g}, {high[c]:.4g}], outside [{lo:.4g}, {hi:.4g}], the range "
                f"(x / 255 - mean) / std gives for pixels 0..255 (mean {mean[c]:g}, std "
                f"{std[c]:g}): it is not normalised (0..255 floats?); pass uint8 images, which "
                "normalise converts, or normalise them with this mean and std first"
            )
