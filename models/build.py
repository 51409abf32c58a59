"""Building a named backbone from its description (`claravid.models.backbones`), with weights.

The description's family picks the module class and the weights conversion from the two dicts
below; nothing else looks at the family. Every module built here exposes ``patch_size``,
``embed_dim``, ``n_blocks``, ``mean``, ``std``, ``get_intermediate_layers``, ``check_input``,
``check_input_size`` and ``freeze_pos_embed``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from torch import nn

from claravid.models.backbones import (
    DEFAULT_BACKBONE,
    BackboneSpec,
    backbone_config,
    backbone_spec,
)
from claravid.models.dinov3 import DinoV3VisionTransformer
from claravid.models.memory import check_memory
from claravid.models.vit import DinoVisionTransformer
from claravid.models.weights import (
    check_family,
    dinov2_state,
    download_official,
    load_backbone_state,
    read_weights_file,
)
from claravid.models.weights_v3 import dinov3_state

Backbone = DinoVisionTransformer | DinoV3VisionTransformer
_MODULES: dict[str, type[Backbone]] = {
    "dinov2": DinoVisionTransformer,
    "dinov3": DinoV3VisionTransformer,
}
# A file's tensors -> official keys of the family, checked (state, model, spec, source).
_STATES: dict[str, Callable[..., dict[str, torch.Tensor]]] = {
    "dinov2": dinov2_state,
    "dinov3": dinov3_state,
}


def build_backbone(
    name: str = DEFAULT_BACKBONE, weights: str | os.PathLike | None = None, **overrides: Any
) -> Backbone:
    """Build a named DINOv2 or DINOv3 backbone, optionally with weights.

    Args:
        name: One of ``BACKBONE_NAMES``.
        weights: ``None`` for a random init; a path to an official ``.pth`` or a Hugging Face
            ``model.safetensors``; or ``"official"`` to download the official DINOv2 checkpoint
            into the torch hub cache (the project's only network access; the DINOv3 files are
            licence-gated and must be given by path).
        **overrides: Constructor arguments replacing the named ones (tiny test models).

    Raises:
        ValueError: an unknown name or argument.
        WeightsError: the file's keys or shapes do not match (listing them), it belongs to the
            other family or to another DINOv3 backbone, or ``"official"`` for licence-gated
            weights.
        ConnectionError: ``"official"`` while offline, naming the URL and the cache path.
        NotEnoughMemoryError: the parameters (plus the weights file, read whole) exceed the
            available memory; checked before anything is allocated.
    """
    spec = backbone_spec(name)
    cfg = backbone_config(name, **overrides)
    path = None
    if weights is not None:
        path = download_official(name) if str(weights) == "official" else Path(weights)
    module = _MODULES[spec.family]
    if torch.get_default_device().type == "cpu":
        # Meta tensors have shapes but no storage: the count costs no memory.
        file_bytes = path.stat().st_size if path is not None and path.is_file() else 0
        check_memory(
            parameter_bytes(spec, cfg) + file_bytes,
            f"backbone {name} (float32{', plus its weights file' if file_bytes else ''})",
        )
    model = module(**cfg, mean=spec.mean, std=spec.std)
    if path is None:
        return model
    load_weights(model, spec, path)
    return model.eval()


def parameter_bytes(spec: BackboneSpec, cfg: dict[str, Any]) -> int:
    """Bytes of the backbone's parameters and buffers in float32, without allocating them."""
    with torch.device("meta"):
        probe = _MODULES[spec.family](**cfg, mean=spec.mean, std=spec.std)
    return sum(t.numel() for t in probe.state_dict().values()) * 4


def load_weights(model: nn.Module, spec: BackboneSpec, path: str | os.PathLike) -> None:
    """Load a weights file into a backbone built from ``spec``, strictly.

    Raises:
        FileNotFoundError: no such file.
        WeightsError: unreadable, the other family's, another backbone's, or mismatched keys.
    """
    source = str(path)
    state = read_weights_file(path)
    check_family(state, spec, source)
    load_backbone_state(model, _STATES[spec.family](state, model, spec, source), source)
