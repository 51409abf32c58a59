"""What a segmenter takes as input, checked in one place (PyTorch model and ONNX Runtime runner).

The input is a batch of normalised float images ``[B, 3, H, W]`` (``(x / 255 - mean) / std``
with the backbone's own mean and std, which depend on its weights: see
`claravid.models.backbones.specs`), with H and W multiples of the patch size
(`claravid.models.grid`).
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
    patch_size: int | None,
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
    grid = f", H and W multiples of {patch_size}" if patch_size else ""
    return f"float images [B,3,H,W], normalised ({stats}){pixels}{grid}"


def _triple(values: Sequence[float]) -> str:
    return "(" + ", ".join(f"{float(v):g}" for v in values) + ")"


#: Beyond this magnitude a float batch cannot be normalised pixels: normalising 0..255 pixels
#: gives values within ±5 with any backbone's statistics (ImageNet's: -2.1..2.6, SAT-493M's:
#: -2.8..4.9), and 0..255 floats reach 25 in all but nearly black images.
RAW_PIXEL_LIMIT = 25.0
#: Within this magnitude everywhere, a batch was normalised and then divided by 255 again
#: (torchgeo's default ``Normalize(mean=0, std=255)`` after ``normalize=True``): an aerial
#: batch normalised once spans about ±2.
TWICE_NORMALISED_LIMIT = 0.05


class InputRangeWarning(UserWarning):
    """A float batch reached a segmenter, which takes float batches as normalised, with values
    that do not look normalised: raw pixels in [0, 1] (torchgeo's convention, no negative value)
    or a batch normalised twice (every value within ±0.05); the labels would be wrong silently."""


def normalised_bound(mean: Sequence[float], std: Sequence[float]) -> float:
    """The largest magnitude ``(x / 255 - mean) / std`` reaches for pixels 0..255."""
    return max(max(m, 1 - m) / abs(s) for m, s in zip(mean, std, strict=True))


def check_value_range(
    low: float, high: float, mean: Sequence[float], std: Sequence[float]
) -> str | None:
    """Refuse a float batch whose values are 0..255 pixels; say when it does not look normalised.

    Args:
        low, high: The batch's smallest and largest value.
        mean, std: The statistics the model normalises with (stated in the messages).

    Returns:
        The text of an `InputRangeWarning` when no value is negative (raw pixels in [0, 1]?) or
        every value is within `TWICE_NORMALISED_LIMIT` (normalised twice?), else None.

    Raises:
        ValueError: a value beyond `RAW_PIXEL_LIMIT` (0..255 pixels as floats).
    """
    stats = f"mean {_triple(mean)}, std {_triple(std)}"
    expects = (
        f"the model, which takes float batches as normalised ((x / 255 - mean) / std, {stats})"
    )
    silence = (
        "if the batch is normalised, silence this with "
        "warnings.filterwarnings('ignore', category=claravid.models.InputRangeWarning)"
    )
    if high > RAW_PIXEL_LIMIT or low < -RAW_PIXEL_LIMIT:
        raise ValueError(
            f"a float batch with values in [{low:.4g}, {high:.4g}] reached the model, which "
            f"takes float batches as normalised (within ±{normalised_bound(mean, std):.1f} with "
            f"{stats}): 0..255 pixels? pass them as uint8 (x.round().to(torch.uint8)), which "
            "the model normalises itself, or normalise them first: (x / 255 - mean) / std"
        )
    if low >= 0:
        return (
            f"a float batch with no negative value (values in [{low:.3g}, {high:.3g}]) reached "
            f"{expects}: raw pixels in [0, 1] (torchgeo's convention)? normalise them with "
            f"(x - mean) / std, or pass uint8 pixels; {silence}"
        )
    if max(-low, high) < TWICE_NORMALISED_LIMIT:
        return (
            f"a float batch with every value within ±{TWICE_NORMALISED_LIMIT:g} (values in "
            f"[{low:.3g}, {high:.3g}]) reached {expects}: normalised twice (torchgeo's default "
            "division by 255 after train_transforms(normalize=True))? normalise once, or pass "
            f"uint8 pixels; {silence}"
        )
    return None


def check_image_batch(
    x: Any,
    patch_size: int | None,
    array_type: type[Any],
    *,
    mean: Sequence[float] | None = None,
    std: Sequence[float] | None = None,
    allow_uint8: bool = False,
) -> None:
    """Raise ``TypeError``/``ValueError`` stating the expected input when ``x`` is not one.

    Args:
        x: The input batch.
        patch_size: H and W must be multiples of it (None: unknown, H and W not checked).
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
    if patch_size:
        check_image_size(int(shape[2]), int(shape[3]), patch_size)
