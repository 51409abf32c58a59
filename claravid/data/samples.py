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
    the bytes of float32. A float image is returned as it is (normalised already)."""
    if image.is_floating_point():
        return image
    mean_ = torch.tensor(mean, dtype=torch.float32, device=image.device).view(3, 1, 1)
    std_ = torch.tensor(std, dtype=torch.float32, device=image.device).view(3, 1, 1)
    return (image.to(torch.float32) / 255.0 - mean_) / std_
