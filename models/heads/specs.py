"""Which segmentation heads there are, and which settings each one takes.

Three heads read the same frozen backbone (docs/models.md, "Heads"):

- ``dpt`` (`claravid.models.heads.dpt`): the ClaraVid paper's protocol and the default;
- ``linear`` (`claravid.models.heads.linear`): DINOv3's linear segmentation protocol;
- ``upernet`` (`claravid.models.heads.upernet`): UperNet on a feature pyramid made of four taps, as
  the DINOv3 paper's geospatial benchmarks use it.

A head's settings are `claravid.models.build_model` arguments (``model.*`` keys of a training
config); a setting the chosen head does not have is an error, not silently ignored. This module
imports nothing heavy (no torch), so the training config checks names without building a model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from torch import nn

#: The head `build_model` builds when none is named (and that checkpoints without a ``head``
#: entry, written before there was a choice, hold).
DEFAULT_HEAD = "dpt"
#: UperNet's width when none is given: `transformers`' ``UperNetConfig`` default and
#: mmsegmentation's ViT UperNet configs.
UPERNET_CHANNELS = 512
#: Dropout of the linear head, DINOv3's linear protocol (channel-wise, training only).
LINEAR_DROPOUT = 0.1


@dataclass(frozen=True)
class HeadSpec:
    """One head.

    Attributes:
        name: ``dpt``, ``linear`` or ``upernet``.
        settings: The `build_model` arguments it takes, beside the backbone's and the classes.
        taps: How many backbone blocks it reads; None: one or more (concatenated).
        min_micro_batch: The fewest images one training forward pass may hold (UperNet's
            BatchNorm after pooling to one cell sees one value per image and channel).
        min_patches: The fewest patches a side of its input (UperNet's coarsest level halves
            the patch grid, so one patch leaves it nothing): `check_input_size`.
        norm: Where its BatchNorm sees the fewest values per channel in training: ``"pooled"``
            (one per image: UperNet's pooling to one cell), ``"grid"`` (one per image and patch:
            the linear head), or None (no BatchNorm: DPT). `check_norm_batch`.
    """

    name: str
    settings: tuple[str, ...]
    taps: int | None
    min_micro_batch: int = 1
    min_patches: int = 1
    norm: str | None = None


HEADS: dict[str, HeadSpec] = {
    "dpt": HeadSpec("dpt", ("layers", "features", "out_channels", "use_cls"), taps=4),
    "linear": HeadSpec("linear", ("layers", "use_cls"), taps=None, norm="grid"),
    "upernet": HeadSpec(
        "upernet", ("layers", "features"), taps=4, min_micro_batch=2, min_patches=2, norm="pooled"
    ),
}
HEAD_NAMES: tuple[str, ...] = tuple(HEADS)
#: Every head setting, with the value that means "not given".
SETTING_DEFAULTS: dict[str, Any] = {
    "layers": None,
    "features": None,
    "out_channels": None,
    "use_cls": False,
}


def head_spec(name: str) -> HeadSpec:
    """The description of head ``name``.

    Raises:
        ValueError: an unknown name (e.g. a typo, or a checkpoint of a newer version), naming
            the known ones.
    """
    spec = HEADS.get(name) if isinstance(name, str) else None
    if spec is None:
        raise ValueError(f"unknown head {name!r}: choose one of {', '.join(HEAD_NAMES)}")
    return spec


def check_head_settings(name: str, settings: Mapping[str, Any], prefix: str = "") -> HeadSpec:
    """Refuse settings the head does not take, and a tap count it cannot use.

    Args:
        name: The head.
        settings: Head settings by name; a value equal to its `SETTING_DEFAULTS` entry counts
            as not given.
        prefix: How messages spell the keys (``"model."`` for a training config).

    Returns:
        The head's description.

    Raises:
        ValueError: an unknown head, a setting of another head (naming the head's own), or a
            ``layers`` list of the wrong length.
    """
    spec = head_spec(name)
    foreign = [
        key
        for key, value in settings.items()
        if key in SETTING_DEFAULTS and key not in spec.settings and value != SETTING_DEFAULTS[key]
    ]
    if foreign:
        key = foreign[0]
        owners = ", ".join(h.name for h in HEADS.values() if key in h.settings)
        raise ValueError(
            f"{prefix}{key} is not a setting of the {name} head (it takes "
            f"{', '.join(prefix + s for s in spec.settings)}; {key} belongs to {owners}): leave "
            f"it unset, or choose a head that has it"
        )
    layers = settings.get("layers")
    if layers is not None:
        check_tap_count(spec, layers, f"{prefix}layers")
    for key, what in (("features", "a positive integer"), ("out_channels", "positive integers")):
        value = settings.get(key)
        values = list(value) if isinstance(value, Sequence) else [value]
        if value is not None and not all(_positive_int(v) for v in values):
            raise ValueError(
                f"{prefix}{key} must be {what} (channel widths), got {value!r}: leave it unset "
                f"for the {name} head's default"
            )
    return spec


def _positive_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def check_tap_count(spec: HeadSpec, layers: Sequence[int], key: str = "layers") -> None:
    """``layers`` holds as many block indices as the head reads.

    Raises:
        ValueError: too many or too few, saying how many the head needs.
    """
    n = len(layers)
    if spec.taps is None and n < 1:
        raise ValueError(f"{key} needs at least one block index for the {spec.name} head")
    if spec.taps is not None and n != spec.taps:
        raise ValueError(
            f"{key} needs {spec.taps} block indices for the {spec.name} head, got {list(layers)}"
        )


def check_input_size(
    name: str, height: int, width: int, patch_size: int, what: str = "inputs", fix: str = ""
) -> None:
    """Refuse an input smaller than the head takes: the one check every entry point makes
    (the forward pass, training crops and windows, evaluation and prediction windows of a
    checkpoint or an ONNX file, export sizes), before any work.

    Args:
        name: The head.
        height: Input height in pixels.
        width: Input width in pixels.
        patch_size: The backbone's patch size.
        what: How the message names the input (``"--window"``, ``"val.window"``).
        fix: What to do, when the default ("use a larger ...") is not what the caller offers.

    Raises:
        ValueError: one line naming the head, its smallest size in patches and pixels, the
            size given and what to do.
    """
    spec = head_spec(name)
    n = spec.min_patches
    if min(height // patch_size, width // patch_size) >= n:
        return
    side = n * patch_size
    raise ValueError(
        f"the {spec.name} head needs {what} of at least {n} x {n} patches ({side}x{side} px at "
        f"patch size {patch_size}; its coarsest level halves the patch grid), got {width}x"
        f"{height} (WxH): {fix or f'use {what} of at least {side} px a side'}"
    )


def check_norm_batch(name: str, batch: int, grid_h: int, grid_w: int, fix: str) -> None:
    """Refuse a training batch whose BatchNorm would see one value per channel (PyTorch's
    "Expected more than 1 value per channel" after the work before it).

    mmsegmentation does not handle it either: its configs train two or more images per GPU
    and drop a last batch of one. Here it is refused up front, saying what to do.

    Args:
        name: The head.
        batch: Images in the forward pass.
        grid_h: Patch rows of each image.
        grid_w: Patch columns of each image.
        fix: What the caller can change (a config key, ``drop_last=True``).

    Raises:
        ValueError: one line naming the head, what its BatchNorm sees and ``fix``.
    """
    spec = head_spec(name)
    if spec.norm is None:
        return
    per_image = 1 if spec.norm == "pooled" else grid_h * grid_w
    if batch * per_image >= 2:
        return
    sees = "one value per image" if spec.norm == "pooled" else "one value per image and patch"
    raise ValueError(
        f"the {spec.name} head trains BatchNorm, which needs more than one value per channel, "
        f"and sees {sees}: {batch} image(s) of {grid_w} x {grid_h} patches give "
        f"{batch * per_image}; {fix}"
    )


def default_layers(spec: HeadSpec, n_blocks: int, four_taps: Sequence[int]) -> tuple[int, ...]:
    """The blocks a head reads when ``layers`` is not given: the last block for the linear
    head (DINOv3's protocol), the backbone's four DPT taps otherwise (evenly spaced blocks
    ending at the last, which the official UperNet and DPT evaluations use too)."""
    if spec.taps is None:
        return (n_blocks - 1,)
    return tuple(int(i) for i in four_taps)


def classifier(in_channels: int, num_classes: int) -> nn.Conv2d:
    """The 1x1 convolution a head ends with, initialised as the official linear and UperNet
    heads are: weights from N(0, 0.01²), zero bias, so training starts near uniform scores."""
    from torch import nn

    conv = nn.Conv2d(in_channels, num_classes, kernel_size=1)
    nn.init.normal_(conv.weight, mean=0.0, std=0.01)
    if conv.bias is None:  # nn.Conv2d makes a bias unless told not to
        raise RuntimeError("a head's classifier was built without a bias")
    nn.init.zeros_(conv.bias)
    return conv
