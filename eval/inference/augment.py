"""Test-time augmentation as the published protocols run it: several scales and a mirror.

Each augmented copy of an image is resized (bilinear) to the size its protocol's rule gives,
mirrored when it is a flipped copy, and run through the sliding windows at that size; its
window-averaged logits are resized back (bilinear, ``align_corners=False``) to the image's own
size (the labels'), mirrored back, and turned into class probabilities (softmax). The
probabilities are averaged over the copies; the prediction is their argmax. That is the merge
of the official DINOv3 evaluation (``make_inference``) and of mmsegmentation's
``SegTTAModel``; the two differ in how a copy's size is chosen (`TTAConfig.rule`):

- ``dinov3``: the copy's small side is ``int(S·r)`` (``S``: `TTAConfig.size`; for ``r < 1``
  rounded up to a multiple of 32), its other side ``int(small·long/short + 0.5)``;
- ``mmseg``: ``Resize(scale_factor=r, keep_ratio=True)``: the target ``(int(W·r + 0.5),
  int(H·r + 0.5))``, then the factor ``min(long'/long, short'/short)`` applied to both sides
  with the same rounding.

Windows inside a copy follow the protocols' rule: a window larger than the copy shrinks to the
copy's side; with the ``dinov3`` rule, a window larger than the copy in both directions becomes
a square of the copy's small side. The copy is never padded to a window, so a model that takes
any size sees what the official code's model sees. (A model that takes patch multiples only is
handed each such window zero-padded at the bottom and right to the next multiple, the padding's
logits cut off: the only place the toolkit departs from the official code, and only for copies
smaller than a window.)

Memory does not grow with the number of copies: one running sum of probabilities at the
image's size [K,H,W] takes every copy in turn, beside the one copy being run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # torch is imported where a copy is resized: settings read this module
    import torch

RULES = ("dinov3", "mmseg")

#: The official DINOv3 sliding windows (crop, stride): the linear probe's evaluation and the
#: Mask2Former inference config.
DINOV3_LINEAR_WINDOW = (512, 341)
DINOV3_M2F_WINDOW = (896, 596)


@dataclass(frozen=True)
class TTAConfig:
    """The augmented copies of an image and how their sizes are chosen.

    Attributes:
        scales: the ratios r, one copy each (with ``flip``, two).
        flip: also run every resized copy mirrored left-right.
        rule: ``dinov3`` (small side ``int(S·r)``, rounded up to a multiple of 32 below 1) or
            ``mmseg`` (``scale_factor`` r with kept aspect ratio).
        size: S of the ``dinov3`` rule, the small side at ratio 1 (the official evaluation
            uses its crop size, 512 or 896); None: the image's own small side at the window
            config's ``scale``, so ratio 1 is the resolution the toolkit evaluates at. The
            ``mmseg`` rule applies its ratios to the image at ``scale`` and takes no size.
    """

    scales: tuple[float, ...] = (1.0,)
    flip: bool = False
    rule: str = "dinov3"
    size: int | None = None

    def __post_init__(self) -> None:
        if self.rule not in RULES:
            raise ValueError(f"unknown TTA rule {self.rule!r}; use one of {', '.join(RULES)}")
        scales = tuple(self.scales) if isinstance(self.scales, Sequence) else (self.scales,)
        if not scales or not all(
            isinstance(r, int | float) and not isinstance(r, bool) and math.isfinite(r)
            and 0 < r <= 8 for r in scales
        ):  # fmt: skip
            raise ValueError(
                f"TTA scales must be one or more ratios in (0, 8] (e.g. 0.9,1,1.1), got "
                f"{self.scales!r}"
            )
        object.__setattr__(self, "scales", tuple(float(r) for r in scales))
        if not isinstance(self.flip, bool):
            raise ValueError(f"TTA flip must be True or False, got {self.flip!r}")
        if self.size is not None and not (
            isinstance(self.size, int) and not isinstance(self.size, bool) and self.size >= 1
        ):
            raise ValueError(f"TTA size must be a positive integer or None, got {self.size!r}")
        if self.size is not None and self.rule != "dinov3":
            raise ValueError("a TTA size (S) belongs to the dinov3 rule; the mmseg rule has none")

    @classmethod
    def preset(cls, name: str, size: int | None = None) -> TTAConfig:
        """A published protocol by name: ``dinov3`` (the Mask2Former evaluation: ratios 0.9,
        0.95, 1, 1.05, 1.1 and the mirror) or ``mmseg`` (the ADE20K configs' ratios 0.5 to 1.75
        by 0.25 and the mirror).

        Raises:
            ValueError: an unknown name.
        """
        if name == "dinov3":
            return cls((0.9, 0.95, 1.0, 1.05, 1.1), True, "dinov3", size)
        if name == "mmseg":
            return cls((0.5, 0.75, 1.0, 1.25, 1.5, 1.75), True, "mmseg", size)
        raise ValueError(f"unknown TTA preset {name!r}; use one of {', '.join(RULES)}")

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> TTAConfig:
        """The config a report, checkpoint or ONNX file recorded (`describe`)."""
        return cls(
            tuple(record.get("scales", (1.0,))),
            bool(record.get("flip", False)),
            str(record.get("rule", "dinov3")),
            record.get("size"),
        )

    def describe(self) -> dict[str, Any]:
        """The record a report and a model file keep: ``rule``, ``scales``, ``flip``,
        ``size``."""
        return {"rule": self.rule, "scales": list(self.scales), "flip": self.flip,
                "size": self.size}  # fmt: skip

    def copies(self) -> list[tuple[float, bool]]:
        """``(ratio, flipped)`` of every copy, in the official order: each ratio, then each
        ratio mirrored."""
        plain = [(r, False) for r in self.scales]
        return plain + [(r, True) for r in self.scales] if self.flip else plain

    def copy_size(
        self, height: int, width: int, ratio: float, scale: float = 1.0
    ) -> tuple[int, int]:
        """(height, width) of the copy at ``ratio`` of an image ``height`` x ``width``, which
        the window config resizes by ``scale`` first."""
        if self.rule == "mmseg":
            return mmseg_size(height, width, ratio * scale)
        short = self.size if self.size is not None else int(min(height, width) * scale + 0.5)
        return dinov3_size(height, width, short, ratio)


def tta_from_flags(
    preset: str | None,
    scales: Sequence[float] | None = None,
    flip: bool = False,
    size: int | None = None,
) -> TTAConfig | bool | None:
    """The augmentation the command-line flags ask for (``claravid.infra.cli.add_tta_flags``):
    ``--tta none``: False (none, whatever the model file records); a preset, its ratios
    replaced by ``--tta-scales`` when given; ``--tta-scales`` and/or ``--flip`` alone: the
    ``dinov3`` rule with those ratios (default 1) and mirror; no flag: None (the model file's).

    Raises:
        ValueError: ``--tta none`` with other TTA flags, or values `TTAConfig` refuses.
    """
    if preset == "none":
        if scales or flip or size is not None:
            raise ValueError("--tta none turns test-time augmentation off: drop --tta-scales, "
                             "--flip and --tta-size, or choose --tta dinov3/mmseg")  # fmt: skip
        return False
    if preset is not None:
        chosen = TTAConfig.preset(preset, size=size)
        return TTAConfig(tuple(scales), True, chosen.rule, size) if scales else chosen
    if scales or flip or size is not None:
        return TTAConfig(tuple(scales or (1.0,)), flip, "dinov3", size)
    return None


def dinov3_size(height: int, width: int, short: int, ratio: float) -> tuple[int, int]:
    """The DINOv3 evaluation's copy size: small side ``int(short·ratio)``, for ``ratio < 1``
    rounded up to a multiple of 32; the other side ``int(small·long/short_side + 0.5)``."""
    small = int(short * ratio)
    if ratio < 1:
        small = math.ceil(small / 32) * 32
    small = max(1, small)
    if height > width:
        return int(small * height / width + 0.5), small
    return small, int(small * width / height + 0.5)


def mmseg_size(height: int, width: int, factor: float) -> tuple[int, int]:
    """mmcv's ``Resize(scale_factor=factor, keep_ratio=True)``: the target size rounded, then
    the largest factor that keeps the aspect ratio within it, rounded again."""
    target = (int(width * factor + 0.5), int(height * factor + 0.5))
    kept = min(max(target) / max(height, width), min(target) / min(height, width))
    return max(1, int(height * kept + 0.5)), max(1, int(width * kept + 0.5))


def copy_window(height: int, width: int, crop: tuple[int, int], rule: str) -> tuple[int, int]:
    """The window used on a copy ``height`` x ``width``: ``crop`` shrunk to the copy's sides;
    under the ``dinov3`` rule a crop larger than the copy both ways becomes a square of the
    copy's small side."""
    ch, cw = crop
    if rule == "dinov3" and ch > height and cw > width:
        ch = cw = min(height, width)
    return min(ch, height), min(cw, width)


def resize(image: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """An image [C,H,W] resized (bilinear, antialiased when shrinking, as PIL resizes)."""
    import torch.nn.functional as F

    if tuple(image.shape[-2:]) == tuple(size):
        return image
    return F.interpolate(
        image[None], size=size, mode="bilinear", align_corners=False, antialias=True
    )[0]


def back_to(logits: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Logits [K,h,w] resized to ``size`` (bilinear, ``align_corners=False``, as the
    protocols resize their predictions to the label)."""
    import torch.nn.functional as F

    if tuple(logits.shape[-2:]) == tuple(size):
        return logits
    return F.interpolate(logits[None], size=size, mode="bilinear", align_corners=False)[0]
