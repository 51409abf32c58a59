"""DINOv3's linear segmentation head: BatchNorm and a 1x1 convolution on the frozen features.

The protocol of the official ADE20K linear evaluation (docs/models.md, "The linear head"): the
patch tokens of the last block, through the backbone's final norm, as a map on the patch grid;
channel-wise dropout (``Dropout2d``, 0.1, training only), BatchNorm, a 1x1 convolution to the
classes, then bilinear upsampling of the logits to the input size. Several tapped blocks (and
the CLS token, ``use_cls``) are concatenated along the channels, as the official head does for
its multi-layer variants.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from claravid.models.heads.specs import LINEAR_DROPOUT, classifier


class LinearHead(nn.Module):
    """Dropout2d -> BatchNorm -> 1x1 conv on the patch grid, logits upsampled to the input.

    Args:
        embed_dim: Backbone token width D.
        num_classes: Output channels (logits).
        num_layers: Tapped blocks whose tokens are concatenated (1: the official protocol).
        use_cls: Concatenate the CLS token of each block to its patch tokens (2D channels).
        dropout: Channel dropout before the BatchNorm, training only.
    """

    def __init__(
        self,
        embed_dim: int,
        num_classes: int,
        num_layers: int = 1,
        use_cls: bool = False,
        dropout: float = LINEAR_DROPOUT,
    ) -> None:
        super().__init__()
        if num_classes < 1:
            raise ValueError(f"num_classes must be >= 1, got {num_classes}")
        if num_layers < 1:
            raise ValueError(f"num_layers must be >= 1, got {num_layers}")
        self.use_cls = use_cls
        channels = embed_dim * num_layers * (2 if use_cls else 1)
        self.dropout = nn.Dropout2d(dropout)
        self.bn = nn.BatchNorm2d(channels)
        self.conv = classifier(channels, num_classes)

    @property
    def num_classes(self) -> int:
        """Number of output channels."""
        return self.conv.out_channels

    def forward(
        self,
        feats: Sequence[tuple[torch.Tensor, torch.Tensor]],
        grid_h: int,
        grid_w: int,
        out_size: Sequence[int],
    ) -> torch.Tensor:
        """Logits [B, K, *out_size] from (patch tokens [B,N,D], CLS [B,D]) pairs."""
        maps = []
        for tokens, cls in feats:
            if self.use_cls:
                tokens = torch.cat((tokens, cls.unsqueeze(1).expand_as(tokens)), dim=-1)
            maps.append(tokens.transpose(1, 2).reshape(tokens.shape[0], -1, grid_h, grid_w))
        x = maps[0] if len(maps) == 1 else torch.cat(maps, dim=1)
        logits = self.conv(self.bn(self.dropout(x)))
        return F.interpolate(logits, size=tuple(out_size), mode="bilinear", align_corners=False)
