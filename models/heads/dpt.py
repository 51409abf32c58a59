"""DPT decoder (Ranftl et al.; as in Depth-Anything) with a segmentation head.

Four backbone layers are reassembled into a feature pyramid at 4x, 2x, 1x and 1/2x the patch
grid (180, 90, 45, 23 at 630x630 with patch 14; 160, 80, 40, 20 at 640x640 with patch 16), fused
from coarse to fine, and classified at the finest level; logits are then upsampled to the input
size. The per-backbone defaults (taps and widths) are in `claravid.models.backbones.specs`.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn


class Reassemble(nn.Module):
    """Tokens of one layer -> a feature map: optional CLS readout, 1x1 projection, resize."""

    def __init__(self, embed_dim: int, out_channels: int, scale: int, use_cls: bool) -> None:
        super().__init__()
        self.readout = (
            nn.Sequential(nn.Linear(2 * embed_dim, embed_dim), nn.GELU()) if use_cls else None
        )
        self.project = nn.Conv2d(embed_dim, out_channels, kernel_size=1)
        if scale == 4:
            self.resize: nn.Module = nn.ConvTranspose2d(out_channels, out_channels, 4, stride=4)
        elif scale == 2:
            self.resize = nn.ConvTranspose2d(out_channels, out_channels, 2, stride=2)
        elif scale == 1:
            self.resize = nn.Identity()
        else:  # half resolution
            self.resize = nn.Conv2d(out_channels, out_channels, 3, stride=2, padding=1)

    def forward(
        self, tokens: torch.Tensor, cls: torch.Tensor, grid_h: int, grid_w: int
    ) -> torch.Tensor:
        if self.readout is not None:
            tokens = self.readout(torch.cat((tokens, cls.unsqueeze(1).expand_as(tokens)), dim=-1))
        x = tokens.transpose(1, 2).reshape(tokens.shape[0], tokens.shape[-1], grid_h, grid_w)
        return self.resize(self.project(x))


class ResidualConvUnit(nn.Module):
    """x + conv(relu(conv(relu(x)))), both 3x3; ReLU not in place (the input is reused)."""

    def __init__(self, features: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(features, features, 3, padding=1)
        self.conv2 = nn.Conv2d(features, features, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.relu(self.conv1(F.relu(x))))


class FusionBlock(nn.Module):
    """Add the lateral input (refined), refine, upsample to the next level, 1x1 conv."""

    def __init__(self, features: int, lateral: bool = True) -> None:
        super().__init__()
        # The coarsest level has no lateral input; no unused parameters (DDP would complain).
        self.res1 = ResidualConvUnit(features) if lateral else None
        self.res2 = ResidualConvUnit(features)
        self.out_conv = nn.Conv2d(features, features, kernel_size=1)

    def forward(
        self, x: torch.Tensor, lateral: torch.Tensor | None, size: Sequence[int]
    ) -> torch.Tensor:
        if lateral is not None and self.res1 is not None:
            x = x + self.res1(lateral)
        x = self.res2(x)
        if tuple(x.shape[-2:]) != tuple(size):
            x = F.interpolate(x, size=size, mode="bilinear", align_corners=True)
        return self.out_conv(x)


class DPTHead(nn.Module):
    """DPT decoder plus segmentation head.

    Args:
        embed_dim: Backbone token width.
        num_classes: Output channels (logits).
        features: Fusion width.
        out_channels: Reassemble widths of the four levels, fine to coarse.
        use_cls: Concatenate the CLS token to each patch token (readout ``project``).
    """

    def __init__(
        self,
        embed_dim: int,
        num_classes: int,
        features: int = 256,
        out_channels: Sequence[int] = (256, 512, 1024, 1024),
        use_cls: bool = False,
    ) -> None:
        super().__init__()
        if len(out_channels) != 4:
            raise ValueError(f"out_channels needs 4 entries (one per level), got {out_channels}")
        if num_classes < 1:
            raise ValueError(f"num_classes must be >= 1, got {num_classes}")
        self.num_classes = num_classes
        self.reassemble = nn.ModuleList(
            Reassemble(embed_dim, c, s, use_cls)
            for c, s in zip(out_channels, (4, 2, 1, 0), strict=True)
        )
        self.layer_rn = nn.ModuleList(
            nn.Conv2d(c, features, 3, padding=1, bias=False) for c in out_channels
        )
        self.fusion = nn.ModuleList(FusionBlock(features, lateral=i < 3) for i in range(4))
        self.head = nn.Sequential(
            nn.Conv2d(features, features, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(features, num_classes, kernel_size=1),
        )

    def forward(
        self,
        feats: Sequence[tuple[torch.Tensor, torch.Tensor]],
        grid_h: int,
        grid_w: int,
        out_size: Sequence[int],
    ) -> torch.Tensor:
        """Logits [B, K, *out_size] from four (patch tokens [B,N,D], CLS [B,D]) pairs."""
        levels = [
            rn(re(tokens, cls, grid_h, grid_w))
            for (tokens, cls), re, rn in zip(feats, self.reassemble, self.layer_rn, strict=True)
        ]
        # Coarse to fine: level 3 (1/2x) -> 2 (1x) -> 1 (2x) -> 0 (4x, kept at its size).
        x = self.fusion[3](levels[3], None, levels[2].shape[-2:])
        x = self.fusion[2](x, levels[2], levels[1].shape[-2:])
        x = self.fusion[1](x, levels[1], levels[0].shape[-2:])
        x = self.fusion[0](x, levels[0], levels[0].shape[-2:])
        logits = self.head(x)
        return F.interpolate(logits, size=tuple(out_size), mode="bilinear", align_corners=False)
