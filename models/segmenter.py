"""The segmenter: a frozen DINOv2 or DINOv3 backbone feeding a trainable DPT head."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

from claravid.models.backbones import DEFAULT_BACKBONE, backbone_spec
from claravid.models.build import Backbone, build_backbone
from claravid.models.dpt import DPTHead
from claravid.models.inputs import check_image_batch
from claravid.models.tracing import is_exporting


class Segmenter(nn.Module):
    """Frozen backbone + DPT head: images [B,3,H,W] -> logits [B,K,H,W].

    The backbone has no gradients, stays in eval mode whatever ``.train()`` says, and runs under
    ``no_grad`` so none of its activations are kept: training memory is the decoder's.

    Args:
        backbone: A backbone from `build_backbone` (frozen here).
        head: The DPT head.
        layers: Backbone block indices fed to the head, fine to coarse.
    """

    def __init__(self, backbone: Backbone, head: DPTHead, layers: Sequence[int]) -> None:
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
    def mean(self) -> tuple[float, float, float]:
        """Per-channel mean (RGB, pixels in [0, 1]) the backbone's weights expect."""
        return self.backbone.mean

    @property
    def std(self) -> tuple[float, float, float]:
        """Per-channel std the backbone's weights expect."""
        return self.backbone.std

    @property
    def num_classes(self) -> int:
        """Number of output channels."""
        return self.head.num_classes

    def num_trainable_parameters(self) -> int:
        """Parameters that receive gradients (the head's)."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def train(self, mode: bool = True) -> Segmenter:
        """Set the head's mode; the frozen backbone always stays in eval mode."""
        super().train(mode)
        self.backbone.eval()
        return self

    def normalise(self, pixels: torch.Tensor) -> torch.Tensor:
        """uint8 pixels [B,3,H,W] -> float32 ``(x / 255 - mean) / std`` on their device."""
        mean = torch.tensor(self.mean, device=pixels.device).view(1, 3, 1, 1)
        std = torch.tensor(self.std, device=pixels.device).view(1, 3, 1, 1)
        return (pixels.float() / 255 - mean) / std

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits [B,K,H,W] of images [B,3,H,W] (H, W patch multiples).

        ``x`` is either uint8 pixels in [0, 255], normalised here with the backbone's own mean
        and std (`normalise`), or a float batch taken as normalised already.

        Raises:
            TypeError: ``x`` is neither a floating-point nor a uint8 tensor (e.g. numpy).
            ValueError: ``x`` is not 4-D with 3 channels, or H/W are not patch multiples.
        """
        if not is_exporting():  # before anything indexes x (shapes are symbols while exporting)
            check_image_batch(
                x, self.patch_size, torch.Tensor, mean=self.mean, std=self.std, allow_uint8=True
            )
        if x.dtype == torch.uint8:
            x = self.normalise(x)
        h, w = x.shape[-2:]
        with torch.no_grad():
            feats = self.backbone.get_intermediate_layers(x, self.layers, return_class_token=True)
        p = self.patch_size
        return self.head(feats, h // p, w // p, (h, w))

    def extra_repr(self) -> str:
        return f"layers={self.layers}, trainable={self.num_trainable_parameters():,}"


def build_model(
    backbone: str = DEFAULT_BACKBONE,
    num_classes: int = 19,
    weights: str | os.PathLike | None = None,
    layers: Sequence[int] | None = None,
    features: int | None = None,
    out_channels: Sequence[int] | None = None,
    use_cls: bool = False,
    backbone_kwargs: dict[str, Any] | None = None,
) -> Segmenter:
    """Build the segmenter with the backbone's DPT defaults.

    Args:
        backbone: A name of ``BACKBONE_NAMES``, e.g. ``"dinov2_vitl14"``, ``"dinov2_vits14_reg"``
            or ``"dinov3_vitl16_sat"``.
        num_classes: Number of logits channels K.
        weights: Backbone weights: ``None`` (random), a ``.pth``/``.safetensors`` path or
            ``"official"`` (DINOv2 only; see `build_backbone`).
        layers: Tapped block indices (default per size, e.g. 4, 11, 17, 23 for ViT-L).
        features: DPT fusion width (default per size).
        out_channels: DPT reassemble widths (default per size).
        use_cls: CLS readout in the reassemble stage.
        backbone_kwargs: Overrides of the backbone architecture (tiny test models).

    Returns:
        A `Segmenter` whose ``model_args`` records these arguments (for checkpoints).

    Raises:
        ValueError: an unknown backbone name (e.g. from a newer checkpoint), naming the known
            ones, or inconsistent head arguments.
    """
    defaults = backbone_spec(backbone).dpt
    backbone_kwargs = dict(backbone_kwargs or {})
    vit = build_backbone(backbone, weights=weights, **backbone_kwargs)
    layers = tuple(layers if layers is not None else defaults.layers)
    features = int(features if features is not None else defaults.features)
    out_channels = tuple(out_channels if out_channels is not None else defaults.out_channels)
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
