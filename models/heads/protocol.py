"""What the segmenter and the export use of a head: the `Head` protocol.

The DPT, linear and UperNet heads (`claravid.models.heads.dpt`, `claravid.models.heads.linear`,
`claravid.models.heads.upernet`) satisfy it; a new head that does plugs into
`claravid.models.segmenter.Segmenter`, training and the ONNX export without the rest of the
package knowing its class. It is the counterpart of the backbones'
`claravid.models.backbones.protocol.Backbone`: the segmenter taps the backbone's blocks
(`Backbone.get_intermediate_layers` with the class token) and hands the pairs to the head. Which
blocks a head reads by default and which settings it takes are its description's
(`claravid.models.heads.specs.HeadSpec`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any, Protocol, runtime_checkable

import torch
from torch import nn


@runtime_checkable
class Head(Protocol):
    """A trainable decoder from a backbone's tapped blocks to per-pixel logits."""

    @property
    def num_classes(self) -> int:
        """Output channels K (the segmenter's and the checkpoint's class count)."""
        ...

    def forward(
        self,
        feats: Sequence[tuple[torch.Tensor, torch.Tensor]],
        grid_h: int,
        grid_w: int,
        out_size: Sequence[int],
    ) -> torch.Tensor:
        """Logits [B, K, *out_size] from the tapped blocks' (patch tokens [B, N, D], CLS [B, D])
        pairs, fine to coarse, on a ``grid_h`` x ``grid_w`` patch grid (N = grid_h * grid_w).
        Traced as is by the ONNX export: sizes come from the arguments, never from Python
        values of a tensor."""
        ...

    def __call__(
        self,
        feats: Sequence[tuple[torch.Tensor, torch.Tensor]],
        grid_h: int,
        grid_w: int,
        out_size: Sequence[int],
    ) -> torch.Tensor:
        """`forward` through ``nn.Module``'s hooks (what the segmenter calls)."""
        ...

    def parameters(self, recurse: bool = True) -> Iterator[nn.Parameter]:
        """The weights training optimises (``nn.Module.parameters``)."""
        ...

    def train(self, mode: bool = True) -> Any:
        """Training or evaluation mode (``nn.Module.train``): BatchNorm and dropout follow it."""
        ...
