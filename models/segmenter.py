"""The segmenter: a frozen DINOv2 backbone feeding a trainable DPT head."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

from claravid.models.dpt import DPT_DEFAULTS, DPTHead
from claravid.models.vit import DinoVisionTransformer, build_backbone


class Segmenter(nn.Module):
    """Frozen backbone + DPT head: normalised images [B,3,H,W] -> logits [B,K,H,W].

    The backbone has no gradients, stays in eval mode whatever ``.train()`` says, and runs under
    ``no_grad`` so none of its activations are kept: training memory is the decoder's.

    Args:
        backbone: The DINOv2 backbone (frozen here).
        head: The DPT head.
        layers: Backbone block indices fed to the head, fine to coarse.
    """

    def __init__(self, backbone: DinoVisionTransformer, head: DPTHead, layers: Sequence[int]):
        super().__init__()
        if len(layers) != 4:
            raise ValueError(f"layers needs 4 block indices, got {list(layers)}")
        bad = [i for i in layers if not 0 <= i < backbone.n_blocks]
        if bad:
            raise ValueError(f"layers {bad} outside the backbone's {backbone.n_blocks} blocks")
        self.backbone = backbone.eval().requires_grad_(False)
        self.head = head
        self.layers = tuple(int(i) for i in layers)
        self.model_args: dict[str, Any] = {}

    @property
    def patch_size(self) -> int:
        """The backbone's patch size: H and W must be multiples of it."""
        return self.backbone.patch_size

    @property
    def num_classes(self) -> int:
        """Number of output channels."""
        return self.head.head[-1].out_channels

    def num_trainable_parameters(self) -> int:
        """Parameters that receive gradients (the head's)."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def train(self, mode: bool = True) -> Segmenter:
        """Set the head's mode; the frozen backbone always stays in eval mode."""
        super().train(mode)
        self.backbone.eval()
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits [B,K,H,W] of normalised float images [B,3,H,W] (H, W patch multiples).

        Raises:
            TypeError: ``x`` is not a floating-point tensor (e.g. a numpy array or uint8).
            ValueError: ``x`` is not 4-D with 3 channels, or H/W are not patch multiples.
        """
        self.backbone.check_input(x)  # before anything indexes x (skipped while exporting)
        h, w = x.shape[-2:]
        with torch.no_grad():
            feats = self.backbone.get_intermediate_layers(x, self.layers, return_class_token=True)
        p = self.patch_size
        return self.head(feats, h // p, w // p, (h, w))

    def extra_repr(self) -> str:
        return f"layers={self.layers}, trainable={self.num_trainable_parameters():,}"


def build_model(
    backbone: str = "dinov2_vitl14",
    num_classes: int = 19,
    weights: str | os.PathLike | None = None,
    layers: Sequence[int] | None = None,
    features: int | None = None,
    out_channels: Sequence[int] | None = None,
    use_cls: bool = False,
    backbone_kwargs: dict[str, Any] | None = None,
) -> Segmenter:
    """Build the segmenter with per-size DPT defaults.

    Args:
        backbone: DINOv2 name, e.g. ``"dinov2_vitl14"`` or ``"dinov2_vits14_reg"``.
        num_classes: Number of logits channels K.
        weights: Backbone weights: ``None`` (random), a ``.pth``/``.safetensors`` path or
            ``"official"`` (see `build_backbone`).
        layers: Tapped block indices (default per size, e.g. 4, 11, 17, 23 for ViT-L).
        features: DPT fusion width (default per size).
        out_channels: DPT reassemble widths (default per size).
        use_cls: CLS readout in the reassemble stage.
        backbone_kwargs: Overrides of the backbone architecture (tiny test models).

    Returns:
        A `Segmenter` whose ``model_args`` records these arguments (for checkpoints).
    """
    backbone_kwargs = dict(backbone_kwargs or {})
    vit = build_backbone(backbone, weights=weights, **backbone_kwargs)
    arch = backbone.removeprefix("dinov2_").removesuffix("_reg")
    defaults = DPT_DEFAULTS[arch]
    layers = tuple(layers if layers is not None else defaults["layers"])  # type: ignore[arg-type]
    features = int(features if features is not None else defaults["features"])  # type: ignore[arg-type]
    out_channels = tuple(
        out_channels if out_channels is not None else defaults["out_channels"]  # type: ignore[arg-type]
    )
    head = DPTHead(vit.embed_dim, num_classes, features, out_channels, use_cls)
    model = Segmenter(vit, head, layers)
    model.model_args = {
        "backbone": backbone,
        "num_classes": int(num_classes),
        "weights": None if weights is None else str(weights),
        "layers": list(layers),
        "features": features,
        "out_channels": [int(c) for c in out_channels],
        "use_cls": bool(use_cls),
        "backbone_kwargs": backbone_kwargs,
    }
    return model
