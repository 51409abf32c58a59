"""Augmentation pipelines over sample dicts (albumentations 2.x).

Training: a random crop at native resolution first (padded at a random position with the
ignore index, 255, when the image is smaller), then colour jitter, brightness/contrast, rotation,
optical or grid distortion and a horizontal flip. Cropping first is what makes this cheap:
augmenting a 630×630 crop takes a few ms, the full 4032×3024 frame hundreds.
The crop window can be drawn before anything is decoded (:meth:`SegmentationTransform.draw_window`
from the frame's size): a dataset that reads regions (``ClaraVidSegmentation``) then decodes
only the window and hands it over with ``sample["crop"] = (x, y, width, height)``; a dataset
that cannot gets its full frame cut here, from the same random draws, so both give the same
sample. Evaluation: the whole frame, untouched. Masks are warped with nearest interpolation and
filled with the ignore index (albumentations 2.x ``fill_mask``; the 1.x names are ignored).

A transform takes and returns the whole sample dict. It receives ``image`` as uint8 [3,H,W]
and ``mask`` as uint8 [H,W] train ids, and returns the image as uint8 [3,h,w], the exact
pixels: the segmenter normalises them itself, on its device, with its backbone's statistics
(``claravid.models.Segmenter``; training and evaluation do it with
``claravid.data.samples.normalise``), so a crop travels there at a quarter of float32's bytes
and a frame is never normalised with another model's numbers. ``normalize=True`` ends the
pipeline with the normalisation instead (float32 images, for models of your own): with the
config's ``mean``/``std``, ImageNet's when it sets none. The dataset casts the mask to its
``mask_dtype`` afterwards; evaluation transforms ask for uint8 (``mask_dtype``), training ones
leave it to the dataset (int64, what a loss takes).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple, cast

os.environ.setdefault("NO_ALBUMENTATIONS_UPDATE", "1")  # it phones home at import otherwise

import albumentations as A
import cv2
import numpy as np
import torch
from omegaconf import Container, OmegaConf

from claravid.data.ignore import IGNORE_INDEX
from claravid.io.headers import MAX_PIXELS
from claravid.io.yamlfile import YamlFileError, load_yaml

#: The largest crop side: no JPEG frame is larger (libjpeg's JPEG_MAX_DIMENSION).
MAX_CROP_SIDE = 65500
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass
class AugmentConfig:
    """Every knob of the pipelines; YAML files override any subset (see ``configs/``).

    Probabilities are per sample; a probability of 0 removes that augmentation. ``mean`` and
    ``std`` (RGB, pixels in [0, 1]) are used only with ``normalize=True`` and by
    ``claravid-train``; None there means the backbone's own statistics.
    """

    crop_height: int = 630
    crop_width: int = 630
    hflip_p: float = 0.5
    color_jitter_p: float = 0.5
    brightness: float = 0.2
    contrast: float = 0.2
    saturation: float = 0.2
    hue: float = 0.02
    lighting_p: float = 0.5  # RandomBrightnessContrast
    brightness_limit: float = 0.2
    contrast_limit: float = 0.2
    rotate_p: float = 0.3
    rotate_limit: float = 15.0
    distortion_p: float = 0.2  # one of optical / grid distortion
    optical_distort_limit: float = 0.05
    grid_distort_limit: float = 0.2
    # None: the backbone's statistics (claravid-train fills them in from the model's backbone;
    # ImageNet's for normalize=True without a model).
    mean: tuple[float, float, float] | None = None
    std: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        """Refuse values the pipelines cannot use, naming the setting (they failed deep inside
        OpenCV or albumentations, at the first sample)."""
        for name in ("crop_height", "crop_width"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError(f"{name}={value!r}: must be an integer number of pixels")
            if not 1 <= value <= MAX_CROP_SIDE:
                raise ValueError(
                    f"{name}={value}: must be between 1 and {MAX_CROP_SIDE} pixels (no JPEG "
                    "frame is larger; a frame smaller than the crop is padded)"
                )
        if self.crop_height * self.crop_width > MAX_PIXELS:
            raise ValueError(
                f"crop_height×crop_width = {self.crop_height}×{self.crop_width} is more than "
                f"the {MAX_PIXELS:,} pixels the readers decode; choose a smaller crop"
            )
        for name in ("hflip_p", "color_jitter_p", "lighting_p", "rotate_p", "distortion_p"):
            value = getattr(self, name)
            if not 0 <= value <= 1:
                raise ValueError(f"{name}={value}: a probability, must be between 0 and 1")
        # None: the backbone's statistics (filled in by claravid-train).
        problem = statistics_problem(self.mean, self.std)
        if problem is not None:
            raise ValueError(f"{problem}; or null for the backbone's statistics")


def statistics_problem(mean: Any, std: Any) -> str | None:
    """What makes input statistics unusable, in words; None when they are usable (or None).

    A mean and a std are three finite numbers each (R, G, B) for pixels in [0, 1]: a mean in
    [0, 1], a std in (0, 1]. Statistics on the 0–255 scale (``mean=[123.7, 116.3, 103.5]``)
    would leave inputs a hundred times off their range; a zero or negative std, or NaN, would
    make every input infinite or NaN.
    """
    for name, values in (("mean", mean), ("std", std)):
        if values is None:
            continue
        numbers = isinstance(values, Sequence) and not isinstance(values, str)
        listed = list(values) if numbers else values
        if not numbers or len(listed) != 3 or not all(_is_number(v) for v in listed):
            return (
                f"{name}={listed!r}: three numbers (R, G, B) for pixels in [0, 1], e.g. "
                "[0.5, 0.4, 0.3]"
            )
        if not all(math.isfinite(v) for v in listed):
            return f"{name}={listed}: not finite"
    given = {name: list(v) for name, v in (("mean", mean), ("std", std)) if v is not None}
    if any(v > 1 for values in given.values() for v in values):
        named = ", ".join(f"{name}={values}" for name, values in given.items())
        return (
            f"{named}: statistics on the 0–255 scale? they are for pixels in [0, 1]: divide "
            "them by 255"
        )
    if mean is not None and min(mean) < 0:
        return f"mean={list(mean)}: must lie in [0, 1]"
    if std is not None and min(std) <= 0:
        return f"std={list(std)}: must be positive"
    return None


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _fields(config: Container) -> dict[str, Any]:
    """A structured config's values as plain Python, keyed by the dataclass's field names."""
    return cast(dict[str, Any], OmegaConf.to_container(config))


def augment_config(overrides: Any = None) -> AugmentConfig:
    """The default config merged with a dict, DictConfig, or YAML file path.

    Unknown keys are an error that names them (OmegaConf's structured-config check).
    """
    base = OmegaConf.structured(AugmentConfig)
    if overrides is None:
        return AugmentConfig(**_fields(base))
    if isinstance(overrides, str | os.PathLike):
        try:  # the strict loader names the file, and a duplicate key with its lines
            overrides = load_yaml(overrides) or {}
        except YamlFileError as error:
            raise ValueError(f"invalid augmentation config {error}") from None
    try:
        merged = OmegaConf.merge(base, overrides)
    except Exception as error:  # omegaconf raises several unrelated types
        raise ValueError(f"invalid augmentation config: {error}") from None
    return AugmentConfig(**_fields(merged))


class CropWindow(NamedTuple):
    """Where a crop is cut from, in the stored frame's pixels (the whole axis when the frame is
    smaller than the crop on it; the crop is then padded)."""

    x: int
    y: int
    width: int
    height: int


def _train_ops(cfg: AugmentConfig) -> list[A.BasicTransform]:
    """The augmentations after the crop (the crop itself is `SegmentationTransform`'s)."""
    # Masks are filled with the one ignore id (every palette's, the loss's and the metrics').
    fill = {"border_mode": cv2.BORDER_CONSTANT, "fill": 0, "fill_mask": IGNORE_INDEX}
    nearest = {"mask_interpolation": cv2.INTER_NEAREST}
    ops: list[A.BasicTransform] = []
    if cfg.color_jitter_p > 0:
        ops.append(
            A.ColorJitter(
                brightness=cfg.brightness,
                contrast=cfg.contrast,
                saturation=cfg.saturation,
                hue=cfg.hue,
                p=cfg.color_jitter_p,
            )
        )
    if cfg.lighting_p > 0:
        ops.append(
            A.RandomBrightnessContrast(
                brightness_limit=cfg.brightness_limit,
                contrast_limit=cfg.contrast_limit,
                p=cfg.lighting_p,
            )
        )
    if cfg.rotate_p > 0:
        ops.append(A.Rotate(limit=cfg.rotate_limit, p=cfg.rotate_p, **fill, **nearest))
    if cfg.distortion_p > 0:
        distortions = [
            A.OpticalDistortion(distort_limit=cfg.optical_distort_limit, **fill, **nearest),
            A.GridDistortion(distort_limit=cfg.grid_distort_limit, **fill, **nearest),
        ]
        ops.append(A.OneOf(distortions, p=cfg.distortion_p))
    if cfg.hflip_p > 0:
        ops.append(A.HorizontalFlip(p=cfg.hflip_p))
    return ops


class SegmentationTransform:
    """A random crop (training), then an albumentations pipeline, applied to a sample dict.

    Args:
        ops: the augmentations after the crop.
        cfg: the config (normalisation, crop size).
        crop: ``(height, width)`` of the random crop; None: no crop (evaluation).
        normalize: end with the normalisation (float32 images, with ``cfg.mean``/``std``, else
            ImageNet's); False (default): uint8 images, normalised where the model runs (the
            random stream is the same: the normalisation draws nothing).
        mask_dtype: the mask dtype the dataset should give samples (None: the dataset's own,
            int64 by default).

    Attributes:
        mask_dtype: as given; ``claravid.data.samples.finish_sample`` reads it.
    """

    def __init__(
        self,
        ops: list[A.BasicTransform],
        cfg: AugmentConfig,
        crop: tuple[int, int] | None = None,
        normalize: bool = False,
        mask_dtype: torch.dtype | None = None,
    ) -> None:
        self.cfg = cfg
        self.crop = crop
        self.mask_dtype = mask_dtype
        if normalize:
            mean = cfg.mean if cfg.mean is not None else IMAGENET_MEAN
            std = cfg.std if cfg.std is not None else IMAGENET_STD
            ops = [*ops, A.Normalize(mean=mean, std=std, max_pixel_value=255.0)]
        # Nothing to do (evaluation, uint8): samples pass through untouched, not copied.
        self.identity = crop is None and not ops
        self.pipeline = A.Compose(ops)

    def draw_window(self, width: int, height: int) -> CropWindow:
        """The random crop window of a ``width`` × ``height`` frame, drawn before decoding.

        Drawn from the pipeline's own generator, so ``pipeline.set_random_seed`` fixes the
        window and the augmentations after it alike.
        """
        if self.crop is None:
            raise ValueError("this transform does not crop (evaluation transforms)")
        crop_h, crop_w = self.crop
        rng = self.pipeline.random_generator
        # Two draws whatever the sizes, so the augmentations after the crop see the same stream.
        x = int(rng.integers(0, max(0, width - crop_w) + 1))
        y = int(rng.integers(0, max(0, height - crop_h) + 1))
        return CropWindow(x, y, min(width, crop_w), min(height, crop_h))

    def _cut_and_pad(
        self, image: np.ndarray, mask: np.ndarray | None, cut: bool
    ) -> tuple[np.ndarray, np.ndarray | None, CropWindow]:
        """Cut the window from a full frame (``cut``), then pad the crop to the crop size."""
        assert self.crop is not None
        if cut:
            window = self.draw_window(image.shape[1], image.shape[0])
            rows = slice(window.y, window.y + window.height)
            cols = slice(window.x, window.x + window.width)
            image = image[rows, cols]
            mask = None if mask is None else mask[rows, cols]
        else:
            window = CropWindow(0, 0, image.shape[1], image.shape[0])
        crop_h, crop_w = self.crop
        h, w = image.shape[:2]
        rng = self.pipeline.random_generator
        top = int(rng.integers(0, max(0, crop_h - h) + 1))
        left = int(rng.integers(0, max(0, crop_w - w) + 1))
        if (h, w) != (crop_h, crop_w):  # a frame smaller than the crop: pad at random
            pad = (top, crop_h - h - top, left, crop_w - w - left)
            image = cv2.copyMakeBorder(
                np.ascontiguousarray(image), *pad, cv2.BORDER_CONSTANT, value=(0, 0, 0)
            )
            if mask is not None:
                mask = cv2.copyMakeBorder(
                    np.ascontiguousarray(mask), *pad, cv2.BORDER_CONSTANT, value=IGNORE_INDEX
                )
        return image, mask, window

    def __call__(self, sample: dict[str, Any]) -> dict[str, Any]:
        image = _to_hwc(sample["image"])
        mask = sample.get("mask")
        if mask is not None:
            mask = np.asarray(mask)
            if mask.shape != image.shape[:2]:
                raise ValueError(
                    f"image {image.shape[1]}×{image.shape[0]} and mask "
                    f"{mask.shape[1]}×{mask.shape[0]} of {sample.get('path', 'a sample')} differ"
                )
            if self.identity:
                return self._untouched(sample, image)
            if mask.dtype != np.uint8:
                mask = mask.astype(np.uint8)  # albumentations warps uint8 masks exactly
        elif self.identity:
            return self._untouched(sample, image)
        if self.crop is not None:
            cut = "crop" not in sample  # a dataset that read the window alone says where
            image, mask, window = self._cut_and_pad(image, mask, cut)
            if cut:
                sample["crop"] = tuple(window)
        if mask is None:
            out = self.pipeline(image=image)
        else:
            out = self.pipeline(image=image, mask=mask)
            sample["mask"] = torch.from_numpy(np.ascontiguousarray(out["mask"]))
        sample["image"] = torch.from_numpy(np.ascontiguousarray(out["image"].transpose(2, 0, 1)))
        return sample

    @staticmethod
    def _untouched(sample: dict[str, Any], image: np.ndarray) -> dict[str, Any]:
        """The sample as it came, its image a uint8 [3,H,W] tensor (a view, not a copy: a
        12-Mpixel frame is not worth copying to change nothing)."""
        if not isinstance(sample["image"], torch.Tensor):
            sample["image"] = torch.from_numpy(image).permute(2, 0, 1)
        return sample

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.pipeline})"


def _to_hwc(image: Any) -> np.ndarray:
    """uint8 [3,H,W] tensor (or H×W×3 array) -> H×W×3 array, a view when possible."""
    if isinstance(image, torch.Tensor):
        return image.permute(1, 2, 0).numpy()
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[0] == 3 and image.shape[2] != 3:
        return image.transpose(1, 2, 0)
    return image


def train_transforms(config: Any = None, normalize: bool = False) -> SegmentationTransform:
    """Random crop first, then photometric and geometric augmentations: uint8 crops, which the
    segmenter normalises with its own statistics on its device.

    With ``normalize=True`` the pipeline ends with the normalisation (float32 crops, with the
    config's ``mean``/``std``, else ImageNet's), for models that do not normalise themselves;
    not inside a torchgeo data module, which divides images by 255 again on the device (keep
    uint8 there: docs/data.md, "With torchgeo and Lightning").
    """
    cfg = config if isinstance(config, AugmentConfig) else augment_config(config)
    crop = (cfg.crop_height, cfg.crop_width)
    return SegmentationTransform(_train_ops(cfg), cfg, crop=crop, normalize=normalize)


def eval_transforms(config: Any = None, normalize: bool = False) -> SegmentationTransform:
    """The full frame, no crop: the exact uint8 pixels and a uint8 mask (a 12-Mpixel frame's
    int64 mask is 96 MB; the segmenter and the metrics take uint8). ``normalize=True``: a
    float32 image normalised with the config's ``mean``/``std``, else ImageNet's."""
    cfg = config if isinstance(config, AugmentConfig) else augment_config(config)
    return SegmentationTransform([], cfg, normalize=normalize, mask_dtype=torch.uint8)
