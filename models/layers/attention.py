"""Multi-head self-attention of both ViT families: a fused q/k/v projection (rows q, k, v), an
optional key-masked bias (DINOv3), optional RoPE on the patch tokens (DINOv3), and SDPA.

Parameter names are the official ones of ``facebookresearch/dinov2`` and ``/dinov3``
(``attn.qkv``, ``attn.qkv.bias_mask``, ``attn.proj``), so the official files load unchanged.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from claravid.models.layers.rope import rope_apply


class MaskedBiasLinear(nn.Linear):
    """The fused q/k/v projection whose bias is multiplied by the buffer ``bias_mask``.

    The official DINOv3 models train with the key bias masked (a key bias adds the same amount to
    every score of a query, which softmax cancels), and store the mask with the weights.
    """

    bias_mask: torch.Tensor  # a buffer, registered only when there is a bias

    def __init__(self, dim: int, bias: bool = True) -> None:
        super().__init__(dim, 3 * dim, bias=bias)
        if bias:
            mask = torch.ones(3 * dim)
            mask[dim : 2 * dim] = 0
            self.register_buffer("bias_mask", mask, persistent=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        bias = None if self.bias is None else self.bias * self.bias_mask.to(self.bias.dtype)
        return F.linear(x, self.weight, bias)


class Attention(nn.Module):
    """Multi-head self-attention with SDPA.

    Args:
        dim: Token width.
        num_heads: Heads (``dim`` must divide by it).
        qkv_bias: A bias on the q/k/v projection.
        mask_k_bias: Multiply that bias by the stored ``bias_mask`` (1 for q, 0 for k, 1 for v),
            as DINOv3 does.
        num_prefix_tokens: Leading tokens without a position (CLS, registers): RoPE, when given
            to `forward`, rotates the queries and keys of the tokens after them only.
    """

    def __init__(
        self,
        dim: int,
        num_heads: int,
        qkv_bias: bool = True,
        mask_k_bias: bool = False,
        num_prefix_tokens: int = 0,
    ) -> None:
        super().__init__()
        if dim % num_heads:
            raise ValueError(f"embed_dim {dim} is not divisible by num_heads {num_heads}")
        self.num_heads = num_heads
        self.num_prefix_tokens = num_prefix_tokens
        if mask_k_bias:
            self.qkv: nn.Linear = MaskedBiasLinear(dim, bias=qkv_bias)
        else:
            self.qkv = nn.Linear(dim, 3 * dim, bias=qkv_bias)
        self.proj = nn.Linear(dim, dim)

    def forward(
        self, x: torch.Tensor, rope: tuple[torch.Tensor, torch.Tensor] | None = None
    ) -> torch.Tensor:
        """Attention over ``x`` [B, N, D]; ``rope``: (sin, cos) [N - prefix, head_dim] or None."""
        b, n, c = x.shape
        qkv = self.qkv(x).reshape(b, n, 3, self.num_heads, c // self.num_heads)
        q, k, v = qkv.permute(2, 0, 3, 1, 4).unbind(0)  # each [B, heads, N, head_dim]
        if rope is not None:
            sin, cos = rope
            p = self.num_prefix_tokens  # a Python int: the split stays static while exporting
            q = torch.cat((q[:, :, :p], rope_apply(q[:, :, p:], sin, cos)), dim=2)
            k = torch.cat((k[:, :, :p], rope_apply(k[:, :, p:], sin, cos)), dim=2)
        x = F.scaled_dot_product_attention(q, k, v)
        return self.proj(x.transpose(1, 2).reshape(b, n, c))
