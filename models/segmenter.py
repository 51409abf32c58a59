"""The segmenter: a DINOv2 or DINOv3 backbone, frozen by default, feeding a trainable head
(DPT, linear or UperNet: `claravid.models.heads.specs`)."""

from __future__ import annotations

import contextlib
import math
import os
import warnings
from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

from claravid.models.backbones.build import Backbone, build_backbone
from claravid.models.backbones.specs import DEFAULT_BACKBONE, DPTDefaults, backbone_spec
from claravid.models.backbones.trunk import block_indices
from claravid.models.heads.dpt import DPTHead
from claravid.models.heads.linear import LinearHead
from claravid.models.heads.protocol import Head
from claravid.models.heads.specs import (
    DEFAULT_HEAD,
    UPERNET_CHANNELS,
    HeadSpec,
    check_head_settings,
    check_input_size,
    check_norm_batch,
    default_layers,
)
from claravid.models.heads.upernet import UperNetHead
from claravid.models.inputs import (
    InputRangeWarning,
    check_image_batch,
    check_value_range,
    input_stats,
)
from claravid.models.layers.tracing import is_exporting

#: Backbone parts that serve pre-training only, so no segmentation loss ever reaches them: the
#: masked-image-modelling token (both families) and DINOv3's norm of the local crops' class
#: tokens (SAT ViT-L, 7B). They stay frozen when the backbone trains (DDP refuses a parameter
#: that never gets a gradient).
PRETRAINING_ONLY = ("mask_token", "local_cls_norm")

Triple = tuple[float, float, float]  # R, G, B


class Segmenter(nn.Module):
    """Backbone + head: images [B,3,H,W] -> logits [B,K,H,W].

    By default the backbone is frozen (the paper's protocol): it has no gradients and runs under
    ``no_grad``, so none of its activations are kept and training memory is the decoder's.
    `unfreeze_backbone` trains it end to end instead. Either way the backbone stays in eval mode
    whatever ``.train()`` says (no dropout or stochastic depth while fine-tuning).

    Args:
        backbone: A backbone from `build_backbone` (frozen here).
        head: The head: any ``nn.Module`` satisfying `claravid.models.heads.protocol.Head`
            (the tapped blocks' (patch tokens, CLS) pairs, the patch grid and the output size
            to logits), e.g. `DPTHead`, `LinearHead`, `UperNetHead`.
        layers: Backbone block indices fed to the head, fine to coarse (four for DPT and
            UperNet, one or more for the linear head).
    """

    def __init__(self, backbone: Backbone, head: Head, layers: Sequence[int]) -> None:
        super().__init__()
        if not isinstance(head, nn.Module) or not isinstance(head, Head):
            raise TypeError(
                f"head must be an nn.Module with num_classes and forward(feats, grid_h, grid_w, "
                f"out_size) (the Head protocol), got {type(head).__name__}"
            )
        if not layers:
            raise ValueError("layers needs at least one block index")
        bad = [i for i in layers if not 0 <= i < backbone.n_blocks]
        if bad:
            raise ValueError(f"layers {bad} outside the backbone's {backbone.n_blocks} blocks")
        block_indices(layers, backbone.n_blocks)  # each block once, or a clear error now
        self.backbone = backbone.eval().requires_grad_(False)
        self.head = head
        self.layers = tuple(int(i) for i in layers)
        self.model_args: dict[str, Any] = {}
        # Statistics other than the backbone's (a checkpoint's training config), and whether
        # the input-range warning was given (once per model).
        self._statistics: tuple[Triple, Triple] | None = None
        self._warned_range = False
        self.backbone_frozen = True

    def freeze_backbone(self) -> Segmenter:
        """No gradients through the backbone, which runs under ``no_grad`` (the default)."""
        self.backbone.requires_grad_(False)
        self.backbone_frozen = True
        return self

    def unfreeze_backbone(self) -> Segmenter:
        """Train end to end: gradients reach every backbone parameter but the pre-training-only
        ones (`PRETRAINING_ONLY`)."""
        self.backbone.requires_grad_(True)
        for name in PRETRAINING_ONLY:
            part = getattr(self.backbone, name, None)
            if part is not None:
                part.requires_grad_(False)
        self.backbone_frozen = False
        return self

    @property
    def patch_size(self) -> int:
        """The backbone's patch size: H and W must be multiples of it."""
        return self.backbone.patch_size

    @property
    def mean(self) -> Triple:
        """Per-channel mean (RGB, pixels in [0, 1]) of the input normalisation: the backbone's
        weights', unless `set_statistics` chose others (a checkpoint's training config)."""
        return self._statistics[0] if self._statistics else self.backbone.mean

    @property
    def std(self) -> Triple:
        """Per-channel std of the input normalisation (see `mean`)."""
        return self._statistics[1] if self._statistics else self.backbone.std

    def set_statistics(
        self, mean: Sequence[float] | None = None, std: Sequence[float] | None = None
    ) -> None:
        """Normalise uint8 input with ``mean`` and ``std`` (RGB, pixels in [0, 1]) instead of
        the backbone's; both None: the backbone's again.

        Raises:
            ValueError: not three finite numbers each, a std not positive, or values on the
                0–255 scale.
        """
        if mean is None and std is None:
            self._statistics = None
            return
        if mean is None or std is None:
            raise ValueError("give mean and std together (or neither: the backbone's)")
        m, s = input_stats(mean, "mean"), input_stats(std, "std")
        usable = all(math.isfinite(v) for v in m + s) and min(m) >= 0 and min(s) > 0
        if not usable or max(m + s) > 1:
            raise ValueError(
                f"statistics mean {list(m)}, std {list(s)}: need finite numbers for pixels in "
                "[0, 1] (mean in [0, 1], std in (0, 1]); divide 0–255 statistics by 255"
            )
        self._statistics = (m, s)

    @property
    def dtype(self) -> torch.dtype:
        """The parameters' dtype: what a float batch is cast to, what uint8 pixels become."""
        return next(self.backbone.parameters()).dtype

    @property
    def num_classes(self) -> int:
        """Number of output channels."""
        return self.head.num_classes

    def num_trainable_parameters(self) -> int:
        """Parameters that receive gradients (the head's, and the backbone's when it trains)."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def train(self, mode: bool = True) -> Segmenter:
        """Set the head's mode; the backbone always stays in eval mode."""
        super().train(mode)
        self.backbone.eval()
        return self

    def normalise(self, pixels: torch.Tensor) -> torch.Tensor:
        """uint8 pixels [B,3,H,W] -> ``(x / 255 - mean) / std`` on their device, computed in
        float32 and given the model's dtype (`dtype`: bfloat16 for a model cast to it).

        Raises:
            TypeError: not a uint8 tensor.
            ValueError: not [B,3,H,W] (e.g. channels last).
        """
        if not isinstance(pixels, torch.Tensor) or pixels.dtype != torch.uint8:
            got = pixels.dtype if isinstance(pixels, torch.Tensor) else type(pixels).__name__
            raise TypeError(
                f"normalise takes uint8 pixels [B,3,H,W], got {got}; a float batch goes to the "
                "model as it is (normalised)"
            )
        if pixels.ndim != 4 or pixels.shape[1] != 3:
            last = pixels.ndim == 4 and pixels.shape[-1] == 3
            hint = ": channels last? x.permute(0, 3, 1, 2)" if last else ""
            raise ValueError(
                f"normalise takes uint8 pixels [B,3,H,W], got shape {list(pixels.shape)}{hint}"
            )
        mean = torch.tensor(self.mean, device=pixels.device).view(1, 3, 1, 1)
        std = torch.tensor(self.std, device=pixels.device).view(1, 3, 1, 1)
        return ((pixels.float() / 255 - mean) / std).to(self.dtype)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits [B,K,H,W] of images [B,3,H,W] (H, W patch multiples).

        ``x`` is either uint8 pixels in [0, 255], normalised here with `mean` and `std` (the
        backbone's own unless `set_statistics` chose others; `normalise`), or a float batch
        taken as normalised already and cast to the model's `dtype` (a float16 batch into a
        float32 model). A float batch that does not look normalised warns once
        (`InputRangeWarning`: no negative value, raw pixels in [0, 1]?; every value within
        ±0.05, normalised twice?).

        Raises:
            TypeError: ``x`` is neither a floating-point nor a uint8 tensor (e.g. numpy).
            ValueError: ``x`` is not 4-D with 3 channels, H/W are not patch multiples, or a
                float batch holds 0..255 pixels (a value beyond ±25).
        """
        if not is_exporting():  # before anything indexes x (shapes are symbols while exporting)
            check_image_batch(
                x, self.patch_size, torch.Tensor, mean=self.mean, std=self.std, allow_uint8=True
            )
            if x.is_floating_point() and not torch.compiler.is_compiling():
                self._check_values(x)  # data-dependent: a compiled graph would break on it
            if "head" in self.model_args:
                head, p = self.model_args["head"], self.patch_size
                check_input_size(head, int(x.shape[-2]), int(x.shape[-1]), p)
                if self.training:
                    fix = (
                        "train on two or more images per batch (a DataLoader's drop_last=True "
                        "drops a last batch of one), or call model.eval() to predict"
                    )
                    check_norm_batch(head, x.shape[0], x.shape[-2] // p, x.shape[-1] // p, fix)
        if x.dtype == torch.uint8:
            x = self.normalise(x)
        elif x.dtype != self.dtype:
            x = x.to(self.dtype)
        h, w = x.shape[-2:]
        with torch.no_grad() if self.backbone_frozen else contextlib.nullcontext():
            feats = self.backbone.get_intermediate_layers(x, self.layers, return_class_token=True)
        p = self.patch_size
        return self.head(feats, h // p, w // p, (h, w))

    def _check_values(self, x: torch.Tensor) -> None:
        """Refuse 0..255 floats; warn once about a batch that does not look normalised."""
        if x.numel() == 0:
            return
        low, high = torch.stack(torch.aminmax(x.detach())).float().tolist()  # one sync
        message = check_value_range(low, high, self.mean, self.std)
        if message is not None and not self._warned_range:
            self._warned_range = True
            warnings.warn(message, InputRangeWarning, stacklevel=3)

    def extra_repr(self) -> str:
        return f"layers={self.layers}, trainable={self.num_trainable_parameters():,}"


def build_model(
    backbone: str = DEFAULT_BACKBONE,
    num_classes: int = 19,
    weights: str | os.PathLike | None = None,
    head: str = DEFAULT_HEAD,
    layers: Sequence[int] | None = None,
    features: int | None = None,
    out_channels: Sequence[int] | None = None,
    use_cls: bool = False,
    backbone_kwargs: dict[str, Any] | None = None,
) -> Segmenter:
    """Build the segmenter: a named backbone and a head with the backbone's defaults.

    Args:
        backbone: A name of ``BACKBONE_NAMES``, e.g. ``"dinov2_vitl14"``, ``"dinov2_vits14_reg"``
            or ``"dinov3_vitl16_sat"``.
        num_classes: Number of logits channels K.
        weights: Backbone weights: ``None`` (random), a ``.pth``/``.safetensors`` path or
            ``"official"`` (DINOv2 only; see `build_backbone`).
        head: ``"dpt"`` (the default), ``"linear"`` or ``"upernet"``
        (`claravid.models.heads.specs`).
        layers: Tapped block indices. DPT and UperNet: four (default per size, e.g. 4, 11, 17,
            23 for ViT-L); linear: one or more, concatenated (default: the last block).
        features: DPT: fusion width (default per size); UperNet: its width (default 512).
        out_channels: DPT only: reassemble widths (default per size).
        use_cls: DPT: CLS readout in the reassemble stage; linear: the CLS token concatenated
            to each patch token.
        backbone_kwargs: Overrides of the backbone architecture (tiny test models).

    Returns:
        A `Segmenter` whose ``model_args`` records the head and its resolved settings (for
        checkpoints: evaluation and export rebuild the same model from them).

    Raises:
        ValueError: an unknown backbone or head name (e.g. from a newer checkpoint), naming the
            known ones; a setting the head does not take; inconsistent head arguments.
    """
    given = {"layers": layers, "features": features, "out_channels": out_channels,
             "use_cls": use_cls}  # fmt: skip
    spec = check_head_settings(head, given)
    defaults = backbone_spec(backbone).dpt
    backbone_kwargs = dict(backbone_kwargs or {})
    vit = build_backbone(backbone, weights=weights, **backbone_kwargs)
    if layers is None:
        layers = default_layers(spec, vit.n_blocks, defaults.layers)
    taps = tuple(layers)
    settings = _head_settings(spec, defaults, taps, features, out_channels, use_cls)
    model = Segmenter(vit, _build_head(spec.name, vit.embed_dim, num_classes, settings), taps)
    model.model_args = {
        "backbone": backbone,
        "num_classes": int(num_classes),
        "weights": None if weights is None else str(weights),
        "head": spec.name,
        **settings,
        "backbone_kwargs": backbone_kwargs,
    }
    return model


def _head_settings(
    spec: HeadSpec,
    dpt: DPTDefaults,
    layers: Sequence[int],
    features: int | None,
    out_channels: Sequence[int] | None,
    use_cls: bool,
) -> dict[str, Any]:
    """The head's own settings, defaults filled in, as plain values (what ``model_args``
    records; DPT's four keys are those of checkpoints written before there was a choice)."""
    if features is None:
        features = dpt.features if spec.name == "dpt" else UPERNET_CHANNELS
    if out_channels is None:
        out_channels = dpt.out_channels
    resolved = {
        "layers": [int(i) for i in layers],
        "features": int(features),
        "out_channels": [int(c) for c in out_channels],
        "use_cls": bool(use_cls),
    }
    return {key: resolved[key] for key in spec.settings}


def _build_head(name: str, embed_dim: int, num_classes: int, settings: dict[str, Any]) -> Head:
    if name == "dpt":
        return DPTHead(
            embed_dim, num_classes, settings["features"], settings["out_channels"],
            settings["use_cls"],
        )  # fmt: skip
    if name == "linear":
        return LinearHead(embed_dim, num_classes, len(settings["layers"]), settings["use_cls"])
    return UperNetHead(embed_dim, num_classes, settings["features"])
