"""What the segmenter, the heads and the export may use of a backbone: the `Backbone` protocol.

Both ViT families (`claravid.models.backbones.dinov2`, `claravid.models.backbones.dinov3`, on the
shared
`claravid.models.backbones.trunk`) satisfy it; a new backbone that does can be used everywhere
without
the rest of the package knowing its class. Which blocks a head taps by default and which
weights a backbone has are its description's (`claravid.models.backbones.specs.BackboneSpec`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import torch


@runtime_checkable
class Backbone(Protocol):
    """A frozen feature extractor on a patch grid.

    Attributes:
        patch_size: Patch side in pixels: inputs are H x W with H, W multiples of it.
        embed_dim: Token width D of every output.
        n_blocks: Number of blocks (valid indices for `get_intermediate_layers`).
        mean: Per-channel input mean (RGB, pixels in [0, 1]) the weights expect.
        std: Per-channel input std.
    """

    patch_size: int
    embed_dim: int
    n_blocks: int
    mean: tuple[float, float, float]
    std: tuple[float, float, float]

    def get_intermediate_layers(
        self,
        x: torch.Tensor,
        n: int | Sequence[int] = 1,
        reshape: bool = False,
        return_class_token: bool = False,
        norm: bool = True,
    ) -> tuple[Any, ...]:
        """Outputs of the chosen blocks (official DINOv2/DINOv3 meaning): patch tokens
        [B, N, D] (or [B, D, H/p, W/p] with ``reshape``), with the CLS token [B, D] as pairs
        when ``return_class_token``."""
        ...

    def check_input(self, x: Any) -> None:
        """Raise ``TypeError``/``ValueError`` unless ``x`` is a float [B, 3, H, W] batch on the
        patch grid."""
        ...

    def check_input_size(self, height: int, width: int) -> None:
        """Raise ``ValueError`` naming the nearest valid sizes unless H, W fit the grid."""
        ...

    def freeze_pos_embed(self, height: int | None, width: int | None = None) -> None:
        """Precompute the positions of one input size (a fixed-size export stores them);
        ``None`` clears them."""
        ...

    def eval(self) -> Any:
        """Evaluation mode (``nn.Module.eval``): the segmenter keeps its backbone in it."""
        ...
