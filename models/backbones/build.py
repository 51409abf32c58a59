"""Building a named backbone from its description (`claravid.models.backbones.specs`), with weights.

The description's family picks the module class from the dict below, and the weights loader
(`claravid.models.weights.loader`) the family's declared formats. Every module built here is a
`claravid.models.backbones.protocol.Backbone`.
"""

from __future__ import annotations

import os
from typing import Any

import torch

from claravid.models.backbones.dinov2 import DinoVisionTransformer
from claravid.models.backbones.dinov3 import DinoV3VisionTransformer
from claravid.models.backbones.memory import check_memory
from claravid.models.backbones.protocol import Backbone
from claravid.models.backbones.specs import (
    DEFAULT_BACKBONE,
    BackboneSpec,
    backbone_config,
    backbone_spec,
)
from claravid.models.backbones.trunk import VisionTransformer
from claravid.models.weights.loader import WeightsSource, load_weights, locate_weights

__all__ = ["Backbone", "build_backbone", "parameter_bytes"]

_MODULES: dict[str, type[VisionTransformer]] = {
    "dinov2": DinoVisionTransformer,
    "dinov3": DinoV3VisionTransformer,
}


def build_backbone(
    name: str = DEFAULT_BACKBONE, weights: str | os.PathLike | None = None, **overrides: Any
) -> VisionTransformer:
    """Build a named DINOv2 or DINOv3 backbone, optionally with weights.

    Args:
        name: One of ``BACKBONE_NAMES``.
        weights: ``None`` for a random init; a path to an official ``.pth``, a Hugging Face or
            timm ``model.safetensors``/``pytorch_model.bin``, or a folder holding one (sharded
            checkpoints too); a Hugging Face hub id such as
            ``"timm/vit_large_patch16_dinov3.sat493m"`` (read from the hub cache, downloaded into
            it when online: needs ``huggingface_hub``); or ``"official"`` to download the
            official DINOv2 checkpoint into the torch hub cache (the DINOv3 files are
            licence-gated and must be given by path). See `claravid.models.weights.loader`.
        **overrides: Constructor arguments replacing the named ones (tiny test models).

    Raises:
        ValueError: an unknown name or argument.
        WeightsError: the weights cannot be found, read or fetched, belong to the other family,
            another size or other pre-training data (naming the backbone they are for), their
            ``config.json`` describes another architecture, they hold NaN, their keys or shapes
            do not match (listing them), or ``"official"`` for licence-gated weights.
        ConnectionError: ``"official"`` while offline, naming the URL and the cache path.
        NotEnoughMemoryError: the parameters (plus the weights file, read whole) exceed the
            available memory; checked before anything is allocated.
    """
    spec = backbone_spec(name)
    cfg = backbone_config(name, **overrides)
    source: WeightsSource | None = None
    if weights is not None:
        source = locate_weights(weights, spec)
    module = _MODULES[spec.family]
    if torch.get_default_device().type == "cpu":
        # Meta tensors have shapes but no storage: the count costs no memory.
        file_bytes = source.nbytes if source is not None else 0
        check_memory(
            parameter_bytes(spec, cfg) + file_bytes,
            f"backbone {name} (float32{', plus its weights file' if file_bytes else ''})",
        )
    model = module(**cfg, mean=spec.mean, std=spec.std)
    if source is None:
        return model
    load_weights(model, spec, source, cfg)
    return model.eval()


def parameter_bytes(spec: BackboneSpec, cfg: dict[str, Any]) -> int:
    """Bytes of the backbone's parameters and buffers in float32, without allocating them."""
    with torch.device("meta"):
        probe = _MODULES[spec.family](**cfg, mean=spec.mean, std=spec.std)
    return sum(t.numel() for t in probe.state_dict().values()) * 4
