"""The patch grid: which image sizes a ViT backbone takes, and what to say about the others.

A backbone cuts its input into square patches (14 pixels for DINOv2, 16 for DINOv3), so every
height and width it sees is a multiple of the patch size. Training crops, sliding windows and
fixed-size ONNX exports all start from the model's natural size (:func:`natural_size`); a size
off the grid is refused with the valid sizes nearest to it, in the terms of the flag or of the
tensor that was wrong. Plain integer arithmetic: importing this module loads no torch.
"""

from __future__ import annotations

import math

#: The paper's window and training crop (ClaraVid supplementary §10.3): 630 = 45 patches of 14.
PAPER_WINDOW = 630


def natural_size(patch_size: int) -> int:
    """A model's natural window (and training crop): the smallest multiple of its patch size
    that covers the paper's 630 pixels: 630 (45 × 14) for DINOv2, 640 (40 × 16) for DINOv3."""
    return math.ceil(PAPER_WINDOW / patch_size) * patch_size


def nearest_multiples(size: int, patch_size: int) -> tuple[int, int]:
    """The two multiples of ``patch_size`` nearest to ``size``, below and above it (the two
    smallest when ``size`` is below one patch); ``(size, size)`` when it is one already."""
    p = patch_size
    if size % p == 0:
        return size, size
    below = size // p * p
    return (below, below + p) if below >= p else (p, 2 * p)


def nearest_sizes(
    height: int, width: int, patch_size: int
) -> tuple[tuple[int, int], tuple[int, int]]:
    """The two (height, width) nearest to the given one that the patch grid divides: each side
    rounded down (the smaller) and up (the larger); a side that fits stays as it is."""
    (h0, h1), (w0, w1) = nearest_multiples(height, patch_size), nearest_multiples(width, patch_size)
    return (h0, w0), (h1, w1)


def patch_fix(height: int, width: int, patch_size: int, prefix: str = "") -> str:
    """``use 624x624 or 640x640``: the two nearest valid sizes, width x height (as every size
    flag takes them), each after ``prefix`` (e.g. ``--size ``)."""
    small, large = nearest_sizes(height, width, patch_size)
    return f"use {prefix}{small[1]}x{small[0]} or {prefix}{large[1]}x{large[0]}"


def padded_size(height: int, width: int, patch_size: int) -> tuple[int, int]:
    """The smallest (H, W) at least as large as the input that the patch grid divides."""
    p = patch_size
    return math.ceil(height / p) * p, math.ceil(width / p) * p


def check_image_size(height: int, width: int, patch_size: int) -> None:
    """Raise ``ValueError`` unless H and W are positive multiples of the patch size.

    The message (a tensor's terms, height x width) suggests the padded size, and the cropped one
    when it is not empty.
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
