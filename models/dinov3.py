"""DINOv3 vision transformer in plain PyTorch, key-compatible with the official checkpoints.

Parameter names follow ``facebookresearch/dinov3`` (``storage_tokens``, ``rope_embed.periods``,
``blocks.N.attn.qkv.bias_mask``, ``ls1.gamma``, ``mlp.w1/w2/w3`` ...) so an official ``.pth``
loads with a strict ``load_state_dict``. What differs from DINOv2 (`claravid.models.vit`):

- patches of 16 pixels and no learned positional embedding: queries and keys of the patch
  tokens are rotated by RoPE (`claravid.models.rope`), so any grid works without resizing a
  table;
- tokens [CLS, 4 storage tokens, patches] (storage tokens are DINOv2's registers);
- the key bias is masked out: ``qkv`` has one bias of 3D values, multiplied by the persistent
  buffer ``bias_mask`` (1 for q, 0 for k, 1 for v) — the 7B model has no qkv bias at all;
- LayerNorm eps 1e-5; SwiGLU feed-forwards with three matrices (w1, w2, w3) in S+, H+ and 7B.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from claravid.models.grid import check_image_size
from claravid.models.inputs import check_image_batch, input_stats
from claravid.models.layers import (
    LayerScale,
    Mlp,
    PatchEmbed,
    block_indices,
    layer_outputs,
    swiglu_hidden,
)
from claravid.models.rope import RopePositionEmbedding, rope_apply
from claravid.models.tracing import is_exporting


class MaskedBiasLinear(nn.Linear):
    """The fused q/k/v projection whose bias is multiplied by the buffer ``bias_mask``.

    The official models train with the key bias masked (a key bias adds the same amount to every
    score of a query, which softmax cancels), and store the mask with the weights.
    """

    bias_mask: torch.Tensor  # a buffer, with a bias

    def __init__(self, dim: int, bias: bool = True) -> None:
        super().__init__(dim, 3 * dim, bias=bias)
        if bias:
            mask = torch.ones(3 * dim)
            mask[dim : 2 * dim] = 0
            self.register_buffer("bias_mask", mask, persistent=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        bias = None if self.bias is None else self.bias * self.bias_mask.to(self.bias.dtype)
        return F.linear(x, self.weight, bias)


class SelfAttention(nn.Module):
    """Multi-head self-attention with RoPE on the patch tokens' queries and keys, and SDPA.

    Args:
        dim: Token width.
        num_heads: Heads; ``dim / num_heads`` must be a multiple of 4 (RoPE).
        qkv_bias: A (key-masked) bias on the q/k/v projection.
        num_prefix_tokens: Leading tokens without a position (CLS and storage tokens).
    """

    def __init__(self, dim: int, num_heads: int, qkv_bias: bool, num_prefix_tokens: int) -> None:
        super().__init__()
        if dim % num_heads:
            raise ValueError(f"embed_dim {dim} is not divisible by num_heads {num_heads}")
        self.num_heads = num_heads
        self.num_prefix_tokens = num_prefix_tokens
        self.qkv = MaskedBiasLinear(dim, bias=qkv_bias)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor, rope: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        b, n, c = x.shape
        qkv = self.qkv(x).reshape(b, n, 3, self.num_heads, c // self.num_heads)
        q, k, v = qkv.permute(2, 0, 3, 1, 4).unbind(0)  # each [B, heads, N, head_dim]
        sin, cos = rope
        p = self.num_prefix_tokens  # a Python int: the split stays static while exporting
        q = torch.cat((q[:, :, :p], rope_apply(q[:, :, p:], sin, cos)), dim=2)
        k = torch.cat((k[:, :, :p], rope_apply(k[:, :, p:], sin, cos)), dim=2)
        x = F.scaled_dot_product_attention(q, k, v)
        return self.proj(x.transpose(1, 2).reshape(b, n, c))


class SwiGLU(nn.Module):
    """w3(silu(w1 x) * w2 x): DINOv3's gated feed-forward (three separate matrices)."""

    def __init__(self, dim: int, hidden: int) -> None:
        super().__init__()
        self.w1 = nn.Linear(dim, hidden)
        self.w2 = nn.Linear(dim, hidden)
        self.w3 = nn.Linear(hidden, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.w3(F.silu(self.w1(x)) * self.w2(x))


class Block(nn.Module):
    """x += ls1(attn(norm1 x, rope)); x += ls2(mlp(norm2 x))."""

    def __init__(self, dim: int, attn: SelfAttention, mlp: nn.Module, eps: float) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=eps)
        self.attn = attn
        self.ls1 = LayerScale(dim)
        self.norm2 = nn.LayerNorm(dim, eps=eps)
        self.mlp = mlp
        self.ls2 = LayerScale(dim)

    def forward(self, x: torch.Tensor, rope: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        x = x + self.ls1(self.attn(self.norm1(x), rope))
        return x + self.ls2(self.mlp(self.norm2(x)))


class DinoV3VisionTransformer(nn.Module):
    """DINOv3 ViT backbone.

    The official sizes' arguments are in `claravid.models.backbones` (``build_backbone``).

    Args:
        embed_dim: Token width D.
        depth: Number of blocks.
        num_heads: Attention heads (D / heads must be a multiple of 4).
        patch_size: Patch side in pixels (16 in the official models).
        mean: Per-channel input mean (RGB, pixels in [0, 1]) of the weights' training data.
        std: Per-channel input std.
        ffn: ``"mlp"`` (GELU MLP, fc1/fc2) or ``"swiglu"`` (w1/w2/w3).
        ffn_ratio: Feed-forward expansion (4 MLP; 6 for S+/H+ and 3 for 7B SwiGLU).
        swiglu_align: SwiGLU hidden width rounded up to a multiple of it (8; 64 for 7B).
        qkv_bias: Bias on the q/k/v projection (all but 7B).
        num_storage_tokens: Extra learned tokens after CLS, without position (4).
        rope_base: RoPE period base (100).
        rope_dtype: The dtype RoPE was trained in, ``"bf16"`` (the distilled models: their
            files hold periods rounded to bfloat16) or ``"fp32"`` (7B). It sets the periods of
            a model built without weights and of files that carry none (Hugging Face, timm);
            an official file's own periods replace them.
        norm_eps: LayerNorm epsilon (1e-5).
        local_cls_norm: Hold the pre-training-only ``local_cls_norm`` LayerNorm (never applied)
            that the SAT-493M ViT-L and the 7B files contain, so they load strictly.
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
        ffn: str = "mlp",
        ffn_ratio: float = 4.0,
        swiglu_align: int = 8,
        qkv_bias: bool = True,
        num_storage_tokens: int = 4,
        rope_base: float = 100.0,
        rope_dtype: str = "fp32",
        norm_eps: float = 1e-5,
        local_cls_norm: bool = False,
    ) -> None:
        super().__init__()
        if embed_dim % num_heads or (embed_dim // num_heads) % 4:
            raise ValueError(
                f"embed_dim {embed_dim} / num_heads {num_heads} must be a whole multiple of 4 "
                "(RoPE rotates pairs of y and x channels)"
            )
        self.embed_dim = self.num_features = embed_dim
        self.patch_size = patch_size
        self.n_blocks = depth
        self.num_heads = num_heads
        self.num_storage_tokens = num_storage_tokens
        self.mean = input_stats(mean, "mean")
        self.std = input_stats(std, "std")
        self.patch_embed = PatchEmbed(patch_size, 3, embed_dim)
        self.cls_token = nn.Parameter(torch.zeros(1, 1, embed_dim))
        if num_storage_tokens:
            self.storage_tokens: nn.Parameter | None = nn.Parameter(
                torch.zeros(1, num_storage_tokens, embed_dim)
            )
        else:
            self.storage_tokens = None
        self.rope_embed = RopePositionEmbedding(embed_dim // num_heads, rope_base, rope_dtype)
        if ffn == "mlp":
            hidden = int(embed_dim * ffn_ratio)
        elif ffn == "swiglu":
            hidden = swiglu_hidden(embed_dim, ffn_ratio, swiglu_align)
        else:
            raise ValueError(f"unknown ffn {ffn!r}: use 'mlp' or 'swiglu'")
        feed_forward = Mlp if ffn == "mlp" else SwiGLU
        self.blocks = nn.ModuleList(
            Block(
                embed_dim,
                SelfAttention(embed_dim, num_heads, qkv_bias, 1 + num_storage_tokens),
                feed_forward(embed_dim, hidden),
                norm_eps,
            )
            for _ in range(depth)
        )
        self.norm = nn.LayerNorm(embed_dim, eps=norm_eps)
        self.local_cls_norm = nn.LayerNorm(embed_dim, eps=norm_eps) if local_cls_norm else None
        # Unused at inference (masked-image pre-training); kept so official files load strictly.
        self.mask_token = nn.Parameter(torch.zeros(1, embed_dim))
        self._init_weights()

    def _init_weights(self) -> None:
        nn.init.normal_(self.cls_token, std=0.02)
        if self.storage_tokens is not None:
            nn.init.normal_(self.storage_tokens, std=0.02)
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)

    @property
    def num_prefix_tokens(self) -> int:
        """CLS plus storage tokens, ahead of the patch tokens."""
        return 1 + self.num_storage_tokens

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

    def freeze_pos_embed(self, height: int | None, width: int | None = None) -> None:
        """Precompute the RoPE sin/cos for one input size (``None`` clears them).

        The DINOv2 counterpart stores an interpolated positional table for a fixed-size ONNX
        export; here there is no table, but storing the rotation angles lets that export hold
        them as constants. Other sizes are still computed, with the same values.
        """
        if height is None:
            self.rope_embed.freeze(None)
            return
        width = height if width is None else width
        self.check_input_size(height, width)
        self.rope_embed.freeze(height // self.patch_size, width // self.patch_size)

    def prepare_tokens(self, x: torch.Tensor) -> torch.Tensor:
        """Image [B,3,H,W] -> tokens [B, 1 + storage + N, D] (no positional term: see RoPE)."""
        self.check_input(x)
        tokens = self.patch_embed(x)
        b = tokens.shape[0]
        prefix = [self.cls_token.expand(b, -1, -1)]
        if self.storage_tokens is not None:
            prefix.append(self.storage_tokens.expand(b, -1, -1))
        return torch.cat([*(t.to(tokens.dtype) for t in prefix), tokens], dim=1)

    def _rope(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h, w = x.shape[-2:]
        return self.rope_embed(h // self.patch_size, w // self.patch_size)

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
            n: The last ``n`` blocks if an int, else the block indices to return.
            reshape: Return patch tokens as [B, D, H/p, W/p] instead of [B, N, D].
            return_class_token: Return (patch tokens, CLS token) pairs.
            norm: Pass each output through the final LayerNorm.

        Returns:
            One entry per requested block, in block order; storage tokens are dropped.
        """
        take = block_indices(n, len(self.blocks))
        self.check_input(x)
        h, w = x.shape[-2:]
        tokens = self.prepare_tokens(x)
        rope = self._rope(x)
        outputs = []
        for i, blk in enumerate(self.blocks[: max(take) + 1]):
            tokens = blk(tokens, rope)
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
        rope = self._rope(x)
        for blk in self.blocks:
            tokens = blk(tokens, rope)
        return self.norm(tokens)[:, 0]
