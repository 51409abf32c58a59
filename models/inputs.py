"""What a segmenter takes as input, checked in one place (PyTorch model and ONNX Runtime runner).

The input is a batch of normalised float images ``[B, 3, H, W]`` (ImageNet mean and std), with H
and W multiples of the patch size. Wrong input otherwise fails deep inside torch ("Sizes of
tensors must match...") or onnxruntime; these checks say what was expected and how to fix it.
"""

from __future__ import annotations

import math
from typing import Any

#: What every message states as the expected input.
EXPECTED = "float images [B,3,H,W], normalised (ImageNet mean/std), H and W multiples of {p}"


def padded_size(height: int, width: int, patch_size: int) -> tuple[int, int]:
    """The smallest (H, W) at least as large as the input that the patch grid divides."""
    p = patch_size
    return math.ceil(height / p) * p, math.ceil(width / p) * p


def check_image_size(height: int, width: int, patch_size: int) -> None:
    """Raise ``ValueError`` unless H and W are positive multiples of the patch size.

    The message suggests the padded size (and the cropped one when it is not empty).
    """
    p = patch_size
    if height <= 0 or width <= 0:
        raise ValueError(
            f"input size {height}x{width} is empty; height and width must be positive multiples "
            f"of the patch size {p} (e.g. {p * 45}x{p * 45})"
        )
    if height % p or width % p:
        ph, pw = padded_size(height, width, p)
        crop = (
            f" (or crop to {height // p * p}x{width // p * p})" if min(height, width) >= p else ""
        )
        raise ValueError(
            f"input size {height}x{width} is not a multiple of the patch size {p}: "
            f"pad or resize it to {ph}x{pw}{crop}"
        )


def check_image_batch(x: Any, patch_size: int, array_type: type) -> None:
    """Raise ``TypeError``/``ValueError`` stating the expected input when ``x`` is not one.

    Args:
        x: The input batch.
        patch_size: H and W must be multiples of it.
        array_type: ``torch.Tensor`` (PyTorch model) or ``numpy.ndarray`` (ONNX Runtime runner).
    """
    expected = EXPECTED.format(p=patch_size)
    if not isinstance(x, array_type):
        hint = ": convert with torch.from_numpy(x)" if type(x).__module__ == "numpy" else ""
        raise TypeError(
            f"expected a {array_type.__module__}.{array_type.__name__} of {expected}; got "
            f"{type(x).__module__}.{type(x).__name__}{hint}"
        )
    shape, dtype = x.shape, x.dtype
    if len(shape) != 4:
        hint = " (add the batch dimension: x[None])" if len(shape) == 3 else ""
        raise ValueError(f"expected {expected}; got shape {list(shape)}{hint}")
    if not (getattr(dtype, "is_floating_point", False) or getattr(dtype, "kind", "") == "f"):
        raise TypeError(
            f"expected {expected}; got dtype {dtype}: convert to float and normalise, "
            "e.g. (x / 255 - mean) / std"
        )
    if shape[1] != 3:
        hint = " (channels last? permute to [B,3,H,W])" if shape[-1] == 3 else ""
        raise ValueError(f"expected {expected}; got {shape[1]} channels in {list(shape)}{hint}")
    check_image_size(int(shape[2]), int(shape[3]), patch_size)
