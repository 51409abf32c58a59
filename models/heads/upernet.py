"""UperNet (Xiao et al. 2018) on a ViT: four taps made a pyramid, then pyramid pooling and an FPN.

A ViT has one resolution, so the four tapped blocks are first resized into a pyramid at 4x, 2x,
1x and 1/2x the patch grid (`ViTPyramid`, mmsegmentation's ``Feature2Pyramid`` neck for ViTs:
two stride-2 transposed convolutions with BatchNorm and GELU between them, one transposed
convolution, identity, 2x2 max-pooling). The head (`UperNetHead`) then follows mmsegmentation's
``UPerHead`` and `transformers`' ``UperNetHead``, with their parameter names: a pyramid pooling
module (average pooling to 1, 2, 3 and 6 cells, a 1x1 conv-BN-ReLU each, upsampled back) on the
coarsest level with a 3x3 bottleneck; 1x1 lateral convs on the other levels and a top-down path
(each coarser level upsampled and added); a 3x3 conv on each level; every level upsampled to the
finest and concatenated; a 3x3 fusion conv; dropout (training only); a 1x1 classifier; and the
logits upsampled to the input. All upsampling is bilinear without ``align_corners``; every conv
but the classifier is conv (no bias) -> BatchNorm -> ReLU. See docs/models.md, "UperNet".
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from claravid.models.heads.specs import HEADS, UPERNET_CHANNELS, classifier
from claravid.models.layers.tracing import is_exporting

POOL_SCALES = (1, 2, 3, 6)


class ConvModule(nn.Module):
    """conv (no bias) -> BatchNorm -> ReLU, with a same-size padding."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(
            in_channels, out_channels, kernel_size, padding=kernel_size // 2, bias=False
        )
        self.bn = nn.BatchNorm2d(out_channels)
        # mmsegmentation's initialisation of its conv modules.
        nn.init.kaiming_normal_(self.conv.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.bn(self.conv(x)))


class ViTPyramid(nn.Module):
    """Four maps on the patch grid [B,D,h,w] -> maps at 4x, 2x, 1x and 1/2x (floor) of it."""

    def __init__(self, embed_dim: int) -> None:
        super().__init__()
        d = embed_dim
        self.upsample_4x = nn.Sequential(
            nn.ConvTranspose2d(d, d, kernel_size=2, stride=2),
            nn.BatchNorm2d(d),
            nn.GELU(),
            nn.ConvTranspose2d(d, d, kernel_size=2, stride=2),
        )
        self.upsample_2x = nn.ConvTranspose2d(d, d, kernel_size=2, stride=2)
        self.downsample_2x = nn.MaxPool2d(kernel_size=2, stride=2)

    def forward(self, maps: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        return [
            self.upsample_4x(maps[0]),
            self.upsample_2x(maps[1]),
            maps[2],
            self.downsample_2x(maps[3]),
        ]


class PoolingStage(nn.Module):
    """Average-pool to ``scale`` x ``scale`` cells, then a 1x1 conv module."""

    def __init__(self, scale: int, in_channels: int, channels: int) -> None:
        super().__init__()
        self.scale = scale
        self.conv = ConvModule(in_channels, channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(adaptive_avg_pool(x, self.scale))


def adaptive_avg_pool(x: torch.Tensor, cells: int) -> torch.Tensor:
    """``F.adaptive_avg_pool2d(x, cells)`` as two products with averaging matrices.

    The same cells (cell i of an axis of length L averages ``floor(i·L/n)`` to
    ``ceil((i+1)·L/n)``, exclusive), written with shape arithmetic that the ONNX exporter keeps
    symbolic: its own decomposition of adaptive pooling bakes in the example's size, so a
    dynamic-size export failed at any other size.
    """
    rows = _averaging_matrix(x.shape[-2], cells, x)
    cols = _averaging_matrix(x.shape[-1], cells, x)
    return rows @ x @ cols.transpose(0, 1)


def _averaging_matrix(length: int, cells: int, like: torch.Tensor) -> torch.Tensor:
    """[cells, length]: row i holds 1/width over the positions cell i averages, 0 elsewhere."""
    i = torch.arange(cells, device=like.device)
    start = torch.div(i * length, cells, rounding_mode="floor")
    end = torch.div((i + 1) * length + cells - 1, cells, rounding_mode="floor")
    j = torch.arange(length, device=like.device)
    inside = (j >= start[:, None]) & (j < end[:, None])
    return inside.to(like.dtype) / (end - start).to(like.dtype)[:, None]


def _resize(x: torch.Tensor, size: Sequence[int]) -> torch.Tensor:
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False)


class UperNetHead(nn.Module):
    """The ViT pyramid and UperNet, taking the segmenter's four taps.

    Args:
        embed_dim: Backbone token width D (every pyramid level keeps it).
        num_classes: Output channels (logits).
        channels: UperNet's width (``features`` of `build_model`).
        pool_scales: Cells per side of the pyramid pooling module.
        dropout: Channel dropout before the classifier, training only (mmsegmentation's 0.1).
    """

    def __init__(
        self,
        embed_dim: int,
        num_classes: int,
        channels: int = UPERNET_CHANNELS,
        pool_scales: Sequence[int] = POOL_SCALES,
        dropout: float = 0.1,
    ) -> None:
        super().__init__()
        if num_classes < 1:
            raise ValueError(f"num_classes must be >= 1, got {num_classes}")
        if channels < 1:
            raise ValueError(f"features (UperNet's width) must be >= 1, got {channels}")
        d, c = embed_dim, channels
        self.neck = ViTPyramid(d)
        self.psp_modules = nn.ModuleList(PoolingStage(s, d, c) for s in pool_scales)
        self.bottleneck = ConvModule(d + len(pool_scales) * c, c, 3)
        self.lateral_convs = nn.ModuleList(ConvModule(d, c, 1) for _ in range(3))
        self.fpn_convs = nn.ModuleList(ConvModule(c, c, 3) for _ in range(3))
        self.fpn_bottleneck = ConvModule(4 * c, c, 3)
        self.dropout = nn.Dropout2d(dropout)
        self.classifier = classifier(c, num_classes)

    @property
    def num_classes(self) -> int:
        """Number of output channels."""
        return self.classifier.out_channels

    def decode(self, levels: Sequence[torch.Tensor]) -> torch.Tensor:
        """UperNet proper: logits [B,K,*] at the finest level of a four-level pyramid (fine to
        coarse), as `transformers`' ``UperNetHead`` computes them from the same inputs."""
        top = levels[3]
        pooled = [_resize(stage(top), top.shape[-2:]) for stage in self.psp_modules]
        laterals = [conv(x) for conv, x in zip(self.lateral_convs, levels[:3], strict=True)]
        laterals.append(self.bottleneck(torch.cat([top, *pooled], dim=1)))
        for i in (3, 2, 1):  # top-down: each level gets the (already summed) coarser one
            laterals[i - 1] = laterals[i - 1] + _resize(laterals[i], laterals[i - 1].shape[-2:])
        outs = [conv(x) for conv, x in zip(self.fpn_convs, laterals[:3], strict=True)]
        outs.append(laterals[3])
        size = outs[0].shape[-2:]
        fused = self.fpn_bottleneck(torch.cat([outs[0], *(_resize(x, size) for x in outs[1:])], 1))
        return self.classifier(self.dropout(fused))

    def forward(
        self,
        feats: Sequence[tuple[torch.Tensor, torch.Tensor]],
        grid_h: int,
        grid_w: int,
        out_size: Sequence[int],
    ) -> torch.Tensor:
        """Logits [B, K, *out_size] from four (patch tokens [B,N,D], CLS [B,D]) pairs.

        Raises:
            ValueError: a grid under 2 patches a side (the coarsest level halves it).
        """
        least = HEADS["upernet"].min_patches  # stated once, checked by every entry point
        if not is_exporting() and min(grid_h, grid_w) < least:
            raise ValueError(
                f"the upernet head needs a patch grid of at least {least} x {least} (its "
                f"coarsest level halves it), got {grid_w} x {grid_h}: use a larger input"
            )
        maps = [t.transpose(1, 2).reshape(t.shape[0], -1, grid_h, grid_w) for t, _ in feats]
        return _resize(self.decode(self.neck(maps)), out_size)
