"""A deliberately plain DINOv2 forward written from the official semantics, for comparisons.

It works on an official-format state dict only (no modules of ours): explicit per-head softmax
attention, LayerNorm/GELU/SiLU from torch.nn.functional, the official positional-embedding
rule ((grid + 0.1) / M scale without registers; exact size with antialias with registers).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F


def random_official_state(model: torch.nn.Module, seed: int = 0) -> dict[str, torch.Tensor]:
    """Random values in the official key layout (LayerNorm weights near 1, the rest small)."""
    g = torch.Generator().manual_seed(seed)
    state = {}
    for key, value in model.state_dict().items():
        noise = torch.randn(value.shape, generator=g)
        if key.endswith(".weight") and "norm" in key:
            state[key] = 1.0 + 0.1 * noise
        elif key in ("pos_embed", "cls_token", "register_tokens"):
            state[key] = noise
        else:
            state[key] = 0.2 * noise if value.ndim > 1 else 0.05 * noise
    return state


def reference_layers(
    state: dict[str, torch.Tensor],
    x: torch.Tensor,
    num_heads: int,
    take: list[int],
    registers: bool,
    norm: bool = True,
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """(patch tokens [B,N,D], CLS [B,D]) of the blocks in ``take``."""
    w = state["patch_embed.proj.weight"]
    dim, p = w.shape[0], w.shape[-1]
    b = x.shape[0]
    t = F.conv2d(x, w, state["patch_embed.proj.bias"], stride=p)
    gh, gw = t.shape[-2:]
    t = t.flatten(2).transpose(1, 2)
    t = torch.cat([state["cls_token"].expand(b, -1, -1), t], dim=1)
    pos = state["pos_embed"]
    m = int(math.sqrt(pos.shape[1] - 1))
    if (gh, gw) != (m, m):
        grid = pos[:, 1:].reshape(1, m, m, dim).permute(0, 3, 1, 2)
        if registers:
            grid = F.interpolate(grid, size=(gh, gw), mode="bicubic", antialias=True)
        else:
            scale = ((gh + 0.1) / m, (gw + 0.1) / m)
            grid = F.interpolate(grid, scale_factor=scale, mode="bicubic")
        pos = torch.cat([pos[:, :1], grid.permute(0, 2, 3, 1).reshape(1, gh * gw, dim)], dim=1)
    t = t + pos
    n_reg = 0
    if registers:
        regs = state["register_tokens"]
        n_reg = regs.shape[1]
        t = torch.cat([t[:, :1], regs.expand(b, -1, -1), t[:, 1:]], dim=1)

    def ln(v, name):
        return F.layer_norm(v, (dim,), state[name + ".weight"], state[name + ".bias"], 1e-6)

    def lin(v, name):
        return v @ state[name + ".weight"].T + state[name + ".bias"]

    hd = dim // num_heads
    outs = []
    depth = 1 + max(int(k.split(".")[1]) for k in state if k.startswith("blocks."))
    for i in range(depth):
        pre = f"blocks.{i}."
        h = ln(t, pre + "norm1")
        qkv = lin(h, pre + "attn.qkv")
        q, k, v = qkv[..., :dim], qkv[..., dim : 2 * dim], qkv[..., 2 * dim :]
        heads = []
        for j in range(num_heads):
            s = slice(j * hd, (j + 1) * hd)
            att = torch.softmax(q[..., s] @ k[..., s].transpose(1, 2) / math.sqrt(hd), dim=-1)
            heads.append(att @ v[..., s])
        t = t + state[pre + "ls1.gamma"] * lin(torch.cat(heads, dim=-1), pre + "attn.proj")
        h = ln(t, pre + "norm2")
        if pre + "mlp.w12.weight" in state:
            z = lin(h, pre + "mlp.w12")
            hidden = z.shape[-1] // 2
            mlp = lin(F.silu(z[..., :hidden]) * z[..., hidden:], pre + "mlp.w3")
        else:
            mlp = lin(F.gelu(lin(h, pre + "mlp.fc1")), pre + "mlp.fc2")
        t = t + state[pre + "ls2.gamma"] * mlp
        if i in take:
            outs.append(ln(t, "norm") if norm else t)
    return [(o[:, 1 + n_reg :], o[:, 0]) for o in outs]


def to_timm_dinov2(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Official DINOv2 keys -> timm's (``_convert_dinov2`` of timm's vision_transformer.py).

    The mask token is dropped; the giant model's SwiGLU ``w12, w3`` -> ``fc1, fc2``; with
    registers, ``register_tokens`` -> ``reg_token`` and the CLS position folded into the token
    (``cls_token + pos_embed[:, 0]``), the table keeping the patch positions only.
    """
    out = {}
    for key, value in state.items():
        if key == "mask_token":
            continue
        key = key.replace(".mlp.w12.", ".mlp.fc1.").replace(".mlp.w3.", ".mlp.fc2.")
        out[key.replace("register_tokens", "reg_token")] = value.clone()
    if "reg_token" in out:
        pos = out["pos_embed"]
        out["cls_token"] = out["cls_token"] + pos[:, :1]
        out["pos_embed"] = pos[:, 1:].clone()
    return out
