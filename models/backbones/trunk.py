"""The ViT trunk that DINOv2 and DINOv3 share: patch embedding, CLS token, blocks, final norm,
input checks, ``get_intermediate_layers`` and ``forward``.

A family (`claravid.models.backbones.dinov2` for DINOv2, `claravid.models.backbones.dinov3` for
DINOv3) adds what
differs, as the official DINOv3 ``layers/`` split it: its extra tokens and how positions enter
(`VisionTransformer.prepare_tokens`: DINOv2 adds a resized positional table to the tokens;
`VisionTransformer.positions`: DINOv3 hands every block the RoPE sines and cosines), and its
attention and feed-forward settings. Outputs follow the official ``get_intermediate_layers``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch import nn

from claravid.models.grid import check_image_size
from claravid.models.inputs import check_image_batch, input_stats
from claravid.models.layers.attention import Attention
from claravid.models.layers.blocks import Block, PatchEmbed
from claravid.models.layers.tracing import is_exporting


def block_indices(n: int | Sequence[int], depth: int) -> list[int]:
    """``get_intermediate_layers``' ``n``: the last ``n`` blocks if an int, else the indices.

    Raises:
        ValueError: indices outside the blocks, none, or one repeated (each block's output is
            returned once, in block order).
    """
    take = list(range(depth - n, depth)) if isinstance(n, int) else [int(i) for i in n]
    bad = [i for i in take if not 0 <= i < depth]
    if bad or not take:
        raise ValueError(f"block indices {take} must be in [0, {depth - 1}] and non-empty")
    repeated = sorted({i for i in take if take.count(i) > 1})
    if repeated:
        raise ValueError(
            f"block indices {take} repeat {', '.join(map(str, repeated))}: give each block once"
        )
    return take


def layer_outputs(
    outputs: list[torch.Tensor],
    norm: nn.Module | None,
    num_prefix_tokens: int,
    grid: tuple[int, int],
    reshape: bool,
    return_class_token: bool,
) -> tuple[Any, ...]:
    """Block outputs [B, T, D] as ``get_intermediate_layers`` returns them: through ``norm``
    when given, prefix tokens (CLS, registers) dropped from the patch tokens, [B, D, h, w] when
    ``reshape``, (patches, CLS) pairs when ``return_class_token``."""
    if norm is not None:
        outputs = [norm(o) for o in outputs]
    cls = [o[:, 0] for o in outputs]
    patches = [o[:, num_prefix_tokens:] for o in outputs]
    if reshape:
        gh, gw = grid
        patches = [
            p.reshape(p.shape[0], gh, gw, -1).permute(0, 3, 1, 2).contiguous() for p in patches
        ]
    if return_class_token:
        return tuple(zip(patches, cls, strict=True))
    return tuple(patches)


class VisionTransformer(nn.Module):
    """What both families' backbones are (see `claravid.models.backbones.protocol.Backbone`).

    A family's ``__init__`` calls this one, registers its own tokens and positions, then
    `_add_blocks`; it implements `prepare_tokens`, `positions`, `num_prefix_tokens` and
    `freeze_pos_embed`.

    Args:
        embed_dim: Token width D.
        depth: Number of blocks.
        num_heads: Attention heads.
        patch_size: Patch side in pixels.
        mean: Per-channel input mean (RGB, pixels in [0, 1]) of the weights' training data.
        std: Per-channel input std.
    """

    def __init__(
        self,
        *,
        embed_dim: int,
        depth: int,
        num_heads: int,
        patch_size: int,
        mean: Sequence[float],
        std: Sequence[float],
    ) -> None:
        super().__init__()
        if embed_dim % num_heads:
            raise ValueError(f"embed_dim {embed_dim} is not divisible by num_heads {num_heads}")
        self.embed_dim = self.num_features = embed_dim
        self.patch_size = patch_size
        self.n_blocks = depth
        self.num_heads = num_heads
        self.mean = input_stats(mean, "mean")
        self.std = input_stats(std, "std")
        self.patch_embed = PatchEmbed(patch_size, 3, embed_dim)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, embed_dim))

    def _add_blocks(
        self,
        attention: Callable[[], Attention],
        feed_forward: Callable[[], nn.Module],
        norm_eps: float,
    ) -> None:
        """The blocks, the final norm and the (pre-training only) mask token."""
        dim = self.embed_dim
        self.blocks = nn.ModuleList(
            Block(dim, attention(), feed_forward(), norm_eps) for _ in range(self.n_blocks)
        )
        self.norm = nn.LayerNorm(dim, eps=norm_eps)
        # Unused at inference (masked-image pre-training); kept so official files load strictly.
        self.mask_token = nn.Parameter(torch.zeros(1, dim))

    @property
    def num_prefix_tokens(self) -> int:
        """Tokens ahead of the patch tokens (CLS and registers)."""
        raise NotImplementedError

    def prepare_tokens(self, x: torch.Tensor) -> torch.Tensor:
        """Image [B,3,H,W] -> tokens [B, prefix + N, D] entering the first block."""
        raise NotImplementedError

    def positions(self, x: torch.Tensor) -> Any:
        """What every block receives besides the tokens for input ``x`` (RoPE's sin and cos),
        or None."""
        return None

    def freeze_pos_embed(self, height: int | None, width: int | None = None) -> None:
        """Precompute the positions of one input size (``None`` clears them), e.g. for a
        fixed-size ONNX export that stores them as constants."""
        raise NotImplementedError

    def check_input_size(self, height: int, width: int) -> None:
        """Raise ``ValueError`` naming the nearest valid sizes unless H, W are patch multiples."""
        check_image_size(height, width, self.patch_size)

    def check_input(self, x: Any) -> None:
        """Raise ``TypeError``/``ValueError`` unless ``x`` is float [B,3,H,W] on the patch grid.

        Skipped while tracing or exporting (shapes may be symbolic there); it holds under
        ``torch.compile``.
        """
        if not is_exporting():
            check_image_batch(x, self.patch_size, torch.Tensor, mean=self.mean, std=self.std)

    def get_intermediate_layers(
        self,
        x: torch.Tensor,
        n: int | Sequence[int] = 1,
        reshape: bool = False,
        return_class_token: bool = False,
        norm: bool = True,
    ) -> tuple[Any, ...]:
        """Outputs of chosen blocks, with the official (DINOv2 and DINOv3) meaning.

        Args:
            x: Images [B, 3, H, W], H and W multiples of the patch size.
            n: The last ``n`` blocks if an int, else the block indices to return (each once).
            reshape: Return patch tokens as [B, D, H/p, W/p] instead of [B, N, D].
            return_class_token: Return (patch tokens, CLS token) pairs.
            norm: Pass each output through the final LayerNorm.

        Returns:
            One entry per requested block, in block order; registers are dropped.
        """
        take = block_indices(n, len(self.blocks))
        self.check_input(x)
        h, w = x.shape[-2:]
        tokens = self.prepare_tokens(x)
        positions = self.positions(x)
        outputs = []
        for i, blk in enumerate(self.blocks[: max(take) + 1]):
            tokens = blk(tokens, positions)
            if i in take:
                outputs.append(tokens)
        grid = (h // self.patch_size, w // self.patch_size)
        return layer_outputs(
            outputs,
            self.norm if norm else None,
            self.num_prefix_tokens,
            grid,
            reshape,
            return_class_token,
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Normalised CLS token [B, D] (the official ``forward`` without a head)."""
        tokens = self.prepare_tokens(x)
        positions = self.positions(x)
        for blk in self.blocks:
            tokens = blk(tokens, positions)
        return self.norm(tokens)[:, 0]
