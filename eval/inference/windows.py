"""Sliding-window inference: full-size logits from a model that sees fixed-size windows.

The image travels as uint8 [3,H,W] (what the datasets hand out, with or without
``eval_transforms``) and is normalised where the model runs, with the config's ``mean``/``std``
or, when it sets none, the model's own (``model.mean``/``model.std`` of a segmenter, the
``normalisation`` an ONNX file records): a 12-Mpixel frame is 36 MB on its way to the device,
not 145 MB of float32 made on the CPU. An image already normalised (float [3,H,W]) is taken as
it is. It is optionally resized by ``scale``, cut into windows of ``window`` pixels (by default
the model's natural size, ``claravid.models.grid.natural_size``: 630×630 for patches of 14, the
paper's window, 640×640 for patches of 16) every ``stride`` pixels, the last window of a row or
column flush with the border; windows go through the model in batches, their logits are summed
into a full-size buffer and divided by how many windows covered each pixel. An image smaller
than a window is padded at the bottom/right with zeros (the mean colour after
normalisation) and the padding is cut off the logits. With ``scale != 1`` the logits are resized
back (bilinear) to the input size, so scores are always against the native-resolution labels.

Precision (``WindowConfig.precision``): ``auto`` runs float32 on a CPU and autocast on CUDA
(bf16 where the GPU supports it, else fp16), as before; ``fp32`` never autocasts; ``bf16`` and
``fp16`` autocast to that type on any device (bf16 is fast on CPUs with AVX512-BF16 or AMX).
The logits are float32 whatever the precision.

Test-time augmentation (``WindowConfig.tta``, :mod:`claravid.eval.inference.augment`) runs these
windows on each resized and mirrored copy and averages the copies' probabilities
(`class_probabilities`); `predict_labels` takes their argmax.

Any model works: a ``torch.nn.Module`` or a callable returning numpy
(``claravid.models.OnnxSegmenter``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeGuard

import numpy as np
import torch
import torch.nn.functional as F

from claravid.data.samples import normalise as normalise_image
from claravid.eval.inference.augment import TTAConfig, back_to, copy_window, resize
from claravid.infra.precision import PRECISIONS, autocast, autocast_dtype
from claravid.models.grid import PAPER_WINDOW, natural_size, patch_fix

Model = Callable[[torch.Tensor], Any]


@dataclass(frozen=True)
class WindowConfig:
    """How an image is cut into windows.

    Attributes:
        size: window height and width (multiples of the model's patch size); None: the model's
            natural size (``claravid.models.grid.natural_size``; ``PAPER_WINDOW`` for a model that
            states no patch size), filled in by :meth:`for_model`.
        stride: step between windows; default two thirds of the window (overlap 1/3).
        scale: resize factor applied to the image first (the paper reports at 0.5).
        batch_size: windows per forward pass.
        precision: ``auto``, ``fp32``, ``bf16`` or ``fp16`` (:mod:`claravid.infra.precision`).
        mean, std: the model's input normalisation of uint8 images (per channel, RGB, on the
            0–1 scale); None: the model's own statistics (:meth:`for_model`). A float image is
            taken as normalised already.
        tta: test-time augmentation (scales and mirror, :mod:`claravid.eval.inference.augment`):
            the prediction is then the argmax of probabilities averaged over the copies
            (`class_probabilities`); None: one copy at ``scale``.
    """

    size: tuple[int, int] | None = None
    stride: tuple[int, int] | None = None
    scale: float = 1.0
    batch_size: int = 4
    precision: str = "auto"
    mean: tuple[float, float, float] | None = None
    std: tuple[float, float, float] | None = None
    tta: TTAConfig | None = None

    def __post_init__(self) -> None:
        if self.tta is not None and not isinstance(self.tta, TTAConfig):
            raise ValueError(
                f"tta must be a TTAConfig (e.g. TTAConfig.preset('dinov3')), got {self.tta!r}"
            )
        if self.precision not in PRECISIONS:
            raise ValueError(
                f"precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}"
            )
        size = _pair(self.size, "window size") if self.size is not None else None
        stride = _pair(self.stride, "stride") if self.stride is not None else None
        object.__setattr__(self, "size", size)
        if size is not None:
            stride = stride or (max(1, size[0] * 2 // 3), max(1, size[1] * 2 // 3))
        object.__setattr__(self, "stride", stride)
        if not (math.isfinite(self.scale) and 0 < self.scale <= 8):
            raise ValueError(f"scale must be in (0, 8], got {self.scale}")
        if self.batch_size < 1:
            raise ValueError(f"batch size must be at least 1, got {self.batch_size}")
        if (self.mean is None) != (self.std is None):
            raise ValueError("give mean and std together, or neither (the model's own)")
        for name in ("mean", "std"):
            if getattr(self, name) is None:
                continue
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != 3 or not all(math.isfinite(v) for v in values):
                raise ValueError(f"{name} must be 3 finite numbers (R, G, B), got {values}")
            object.__setattr__(self, name, values)
        if self.std is not None and min(self.std) <= 0:
            raise ValueError(f"std must be positive, got {self.std}")
        if (
            size is not None
            and stride is not None
            and any(s > w for s, w in zip(stride, size, strict=True))
        ):
            raise ValueError(
                f"stride {self.stride} larger than the window {size} would skip pixels"
            )

    def check_patch(self, patch_size: int) -> None:
        """Raise when the window is not a multiple of the model's patch size, naming the two
        nearest sizes that are."""
        if self.size is not None and any(s % patch_size for s in self.size):
            # Width x height, as --window takes it (size is height, width).
            raise ValueError(
                f"window {self.size[1]}x{self.size[0]} (WxH) is not a multiple of the model's "
                f"patch size {patch_size}: {patch_fix(*self.size, patch_size)}"
            )

    def for_model(self, model: Any) -> WindowConfig:
        """This config with what it leaves to the model filled in from it: the window (the
        model's natural size, from its ``patch_size``) and the statistics (``model.mean`` and
        ``model.std``, or an ONNX file's recorded ``normalisation``); checked against the
        model's patch size.

        Raises:
            ValueError: the window is not a multiple of the model's patch size.
        """
        patch = getattr(model, "patch_size", None)
        size, stride = self.size, self.stride
        if size is None:
            side = natural_size(int(patch)) if patch else PAPER_WINDOW
            size = (side, side)
        mean, std = self.mean, self.std
        if mean is None:
            mean, std = model_statistics(model)
        config = dataclasses.replace(self, size=size, stride=stride, mean=mean, std=std)
        if patch:
            config.check_patch(int(patch))
        return config


def model_statistics(model: Any) -> tuple[Any, Any]:
    """``(mean, std)`` a model states for its input: a segmenter's ``mean``/``std`` (its
    backbone's), an ONNX runner's recorded ``normalisation``; ``(None, None)`` otherwise."""
    mean, std = getattr(model, "mean", None), getattr(model, "std", None)
    if _triple(mean) and _triple(std):
        return tuple(mean), tuple(std)
    recorded = getattr(model, "normalisation", None)
    if (
        isinstance(recorded, dict)
        and _triple(recorded.get("mean"))
        and _triple(recorded.get("std"))
    ):
        return tuple(recorded["mean"]), tuple(recorded["std"])
    return None, None


def _triple(value: Any) -> TypeGuard[list[Any] | tuple[Any, ...]]:
    return isinstance(value, list | tuple) and len(value) == 3


def _pair(value: Any, what: str) -> tuple[int, int]:
    pair = (value, value) if isinstance(value, int) else tuple(value)
    if len(pair) != 2 or any(int(v) != v or v < 1 for v in pair):
        raise ValueError(f"{what} must be a positive integer or a pair of them, got {value!r}")
    return int(pair[0]), int(pair[1])


def window_starts(length: int, window: int, stride: int) -> list[int]:
    """Start offsets along one axis: every ``stride``, the last window flush with the end."""
    if length <= window:
        return [0]
    starts = list(range(0, length - window + 1, stride))
    if starts[-1] != length - window:
        starts.append(length - window)
    return starts


def normalise(image: torch.Tensor, config: WindowConfig) -> torch.Tensor:
    """A uint8 image [3,H,W] as the model's float32 input, on the image's device; a float image
    is returned as it is when normalised already (``claravid.data.samples.normalise`` refuses one
    whose values lie outside the normalised range, such as 0..255 floats).

    Raises:
        ValueError: a uint8 image and no statistics (neither the config's nor the model's).
    """
    if config.mean is None or config.std is None:  # both or neither (WindowConfig)
        if not image.is_floating_point():
            raise ValueError(
                "uint8 images need the model's mean and std, and neither the window config nor "
                "the model states them: pass WindowConfig(mean=..., std=...)"
            )
        return image  # no statistics to check its range against: taken as normalised
    return normalise_image(image, config.mean, config.std)


def _forward(model: Model, batch: torch.Tensor, config: WindowConfig) -> torch.Tensor:
    # (An ONNX Runtime session runs at its file's precision: autocast does not reach it.)
    dtype = autocast_dtype(config.precision, batch.device)
    with torch.inference_mode(), autocast(dtype, batch.device):
        out = model(batch)
    if not isinstance(out, torch.Tensor):
        out = torch.from_numpy(np.asarray(out))
    return out.to(batch.device, torch.float32)


def window_average(
    model: Model,
    image: torch.Tensor,
    window: tuple[int, int],
    stride: tuple[int, int],
    config: WindowConfig,
    pad_to: tuple[int, int] | None = None,
) -> torch.Tensor:
    """Window-averaged logits [K,H,W] (float32) of a normalised image [3,H,W] at least one
    ``window`` in size: windows every ``stride``, the last of a row or column flush with the
    border (`window_starts`), their logits summed in place and divided by how many windows
    covered each pixel.

    ``pad_to``: a larger size each window is padded to (zeros at the bottom and right) before
    the model sees it, the padding's logits cut off again (for a model that takes patch
    multiples only, given a window that is not one).
    """
    (h, w), (wh, ww), (sh, sw) = image.shape[-2:], window, stride
    boxes = [(y, x) for y in window_starts(h, wh, sh) for x in window_starts(w, ww, sw)]
    logits: torch.Tensor | None = None
    hits = torch.zeros((h, w), dtype=torch.float32, device=image.device)
    for i in range(0, len(boxes), config.batch_size):
        chunk = boxes[i : i + config.batch_size]
        batch = torch.stack([image[:, y : y + wh, x : x + ww] for y, x in chunk])
        if pad_to is not None and tuple(pad_to) != (wh, ww):
            batch = F.pad(batch, (0, pad_to[1] - ww, 0, pad_to[0] - wh))
        out = _forward(model, batch.contiguous(), config)[..., :wh, :ww]
        if logits is None:
            logits = torch.zeros((out.shape[1], h, w), dtype=torch.float32, device=image.device)
        for (y, x), window_logits in zip(chunk, out, strict=True):
            logits[:, y : y + wh, x : x + ww] += window_logits
            hits[y : y + wh, x : x + ww] += 1
    assert logits is not None  # at least one window always exists
    return logits.div_(hits)


def sliding_window_logits(
    model: Model, image: torch.Tensor, config: WindowConfig | None = None
) -> torch.Tensor:
    """Logits [K,H,W] (float32, on the image's device) of an image [3,H,W].

    Args:
        model: maps [B,3,h,w] float to [B,K,h,w] logits (tensor or numpy).
        image: uint8 (normalised here, with ``config.mean``/``std``, else the model's own) or
            already normalised float, on the device the model runs on.
        config: window size, stride, scale, batch size, precision, normalisation (what it
            leaves unset comes from the model: `WindowConfig.for_model`).

    Raises:
        ValueError: the config asks for test-time augmentation, which averages probabilities,
            not logits (`class_probabilities`).
    """
    config = (config or WindowConfig()).for_model(model)
    if config.tta is not None:
        raise ValueError(
            "test-time augmentation averages probabilities, not logits: use "
            "class_probabilities (or predict_labels) with a config that sets tta"
        )
    _check_image(image)
    image = normalise(image, config)
    full_h, full_w = image.shape[-2:]
    if config.scale != 1.0:
        size = (max(1, round(full_h * config.scale)), max(1, round(full_w * config.scale)))
        image = F.interpolate(
            image[None], size=size, mode="bilinear", align_corners=False, antialias=True
        )[0]
    h, w = image.shape[-2:]
    assert config.size is not None and config.stride is not None  # for_model sets both
    (wh, ww), (sh, sw) = config.size, config.stride
    if h < wh or w < ww:  # pad to one window; the padding is cut off below
        image = F.pad(image, (0, max(0, ww - w), 0, max(0, wh - h)))
    logits = window_average(model, image, (wh, ww), (sh, sw), config)[:, :h, :w]
    if (h, w) != (full_h, full_w):
        logits = F.interpolate(
            logits[None], size=(full_h, full_w), mode="bilinear", align_corners=False
        )[0]
    return logits


def _check_image(image: torch.Tensor) -> None:
    if (
        image.ndim != 3
        or image.shape[0] != 3
        or not (image.is_floating_point() or image.dtype == torch.uint8)
    ):
        raise ValueError(
            f"expected a uint8 or normalised float image [3,H,W], got {tuple(image.shape)} "
            f"{image.dtype}"
        )


def class_probabilities(
    model: Model, image: torch.Tensor, config: WindowConfig | None = None
) -> torch.Tensor:
    """Class probabilities [K,H,W] (float32, on the image's device) of an image [3,H,W]: the
    softmax of the window logits, or with ``config.tta`` their mean over the augmented copies
    (:mod:`claravid.eval.inference.augment`), at the image's own size.

    One running sum [K,H,W] takes the copies in turn, so memory does not grow with them.
    """
    config = (config or WindowConfig()).for_model(model)
    if config.tta is None:
        return sliding_window_logits(model, image, config).softmax(0)
    _check_image(image)
    tta, single = config.tta, dataclasses.replace(config, tta=None)
    image = normalise(image, config)
    full = (int(image.shape[-2]), int(image.shape[-1]))
    assert config.size is not None and config.stride is not None  # for_model sets both
    total: torch.Tensor | None = None
    copies = tta.copies()
    for ratio, flipped in copies:
        copy = resize(image, tta.copy_size(*full, ratio, config.scale))
        if flipped:
            copy = copy.flip(-1)
        window = copy_window(int(copy.shape[-2]), int(copy.shape[-1]), config.size, tta.rule)
        logits = window_average(model, copy, window, config.stride, single,
                                _model_input(model, window))  # fmt: skip
        del copy
        logits = back_to(logits, full)
        if flipped:
            logits = logits.flip(-1)
        probs = logits.softmax(0)
        del logits
        total = probs if total is None else total.add_(probs)
        del probs
    assert total is not None  # a TTAConfig has at least one scale
    return total.div_(len(copies))


def _model_input(model: Model, window: tuple[int, int]) -> tuple[int, int] | None:
    """The size a window is padded to for a model that cannot take it as it is: an ONNX
    file's fixed input, or the next multiple of the model's patch size; None: as it is."""
    fixed = getattr(model, "input_size", None)
    if fixed is not None:
        return (int(fixed[0]), int(fixed[1]))
    patch = getattr(model, "patch_size", None)
    if not patch:
        return None
    p = int(patch)
    return (-(-window[0] // p) * p, -(-window[1] // p) * p)


def predict_labels(
    model: Model, image: torch.Tensor, config: WindowConfig | None = None
) -> torch.Tensor:
    """Train ids [H,W] (int64) of an image [3,H,W] (uint8 or normalised float): argmax of the
    window logits, or with ``config.tta`` of the probabilities averaged over the copies."""
    config = (config or WindowConfig()).for_model(model)
    if config.tta is not None:
        return class_probabilities(model, image, config).argmax(0)
    return sliding_window_logits(model, image, config).argmax(0)
