"""What a segmenter takes as input, checked in one place (PyTorch model and ONNX Runtime runner).

The input is a batch of normalised float images ``[B, 3, H, W]`` (``(x / 255 - mean) / std``
with the backbone's own mean and std, which depend on its weights: see
`claravid.models.backbones`), with H and W multiples of the patch size (`claravid.models.grid`).
The PyTorch segmenter also takes uint8 pixels and normalises them itself. Wrong input otherwise
fails deep inside torch ("Sizes of tensors must match...") or onnxruntime; these checks say what
was expected and how to fix it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from claravid.models.grid import check_image_size


def input_stats(values: Sequence[float], what: str = "mean") -> tuple[float, float, float]:
    """``values`` as three floats (R, G, B), or ``ValueError``."""
    out = tuple(float(v) for v in values)
    if len(out) != 3:
        raise ValueError(f"{what} needs 3 values (R, G, B), got {list(values)}")
    return out


def expected_input(
    patch_size: int,
    mean: Sequence[float] | None = None,
    std: Sequence[float] | None = None,
    allow_uint8: bool = False,
) -> str:
    """What every message states as the expected input (with the statistics when known)."""
    if mean is not None and std is not None:
        stats = f"mean {_triple(mean)}, std {_triple(std)}"
    else:
        stats = "the backbone's mean/std"
    pixels = " or uint8 pixels [B,3,H,W] in [0, 255]" if allow_uint8 else ""
    return (
        f"float images [B,3,H,W], normalised ({stats}){pixels}, H and W multiples of {patch_size}"
    )


def _triple(values: Sequence[float]) -> str:
    return "(" + ", ".join(f"{float(v):g}" for v in values) + ")"


def check_image_batch(
    x: Any,
    patch_size: int,
    array_type: type[Any],
    *,
    mean: Sequence[float] | None = None,
    std: Sequence[float] | None = None,
    allow_uint8: bool = False,
) -> None:
    """Raise ``TypeError``/``ValueError`` stating the expected input when ``x`` is not one.

    Args:
        x: The input batch.
        patch_size: H and W must be multiples of it.
        array_type: ``torch.Tensor`` (PyTorch model) or ``numpy.ndarray`` (ONNX Runtime runner).
        mean: The normalisation's mean, stated in the messages when given.
        std: The normalisation's std.
        allow_uint8: Also accept uint8 pixels (the PyTorch segmenter normalises them).
    """
    expected = expected_input(patch_size, mean, std, allow_uint8)
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
    floating = getattr(dtype, "is_floating_point", False) or getattr(dtype, "kind", "") == "f"
    if not floating and not (allow_uint8 and str(dtype).removeprefix("torch.") == "uint8"):
        raise TypeError(
            f"expected {expected}; got dtype {dtype}: convert to float and normalise, "
            "e.g. (x / 255 - mean) / std"
        )
    if shape[1] != 3:
        hint = " (channels last? permute to [B,3,H,W])" if shape[-1] == 3 else ""
        raise ValueError(f"expected {expected}; got {shape[1]} channels in {list(shape)}{hint}")
    check_image_size(int(shape[2]), int(shape[3]), patch_size)
