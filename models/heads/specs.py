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
    """

    name: str
    settings: tuple[str, ...]
    taps: int | None
    min_micro_batch: int = 1


HEADS: dict[str, HeadSpec] = {
    "dpt": HeadSpec("dpt", ("layers", "features", "out_channels", "use_cls"), taps=4),
    "linear": HeadSpec("linear", ("layers", "use_cls"), taps=None),
    "upernet": HeadSpec("upernet", ("layers", "features"), taps=4, min_micro_batch=2),
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
    return spec


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
