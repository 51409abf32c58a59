"""DINOv2 weights: official and Hugging Face key formats, file loading, the official download.

Our parameter names are the official ones, so an official ``.pth`` needs no mapping. A Hugging
Face ``Dinov2Model`` / ``Dinov2WithRegistersModel`` ``model.safetensors`` is renamed key by key,
with its separate query/key/value projections concatenated into ``qkv`` (rows q, k, v).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import torch
from torch import nn

from claravid.models.torchfile import read_tensor_file

BASE_URL = "https://dl.fbaipublicfiles.com/dinov2"

# Hugging Face parameter name inside one block -> official name.
_HF_BLOCK = {"layer_scale1.lambda1": "ls1.gamma", "layer_scale2.lambda1": "ls2.gamma"}
for _hf, _official in [
    ("norm1", "norm1"),
    ("norm2", "norm2"),
    ("attention.output.dense", "attn.proj"),
    ("mlp.fc1", "mlp.fc1"),
    ("mlp.fc2", "mlp.fc2"),
    ("mlp.weights_in", "mlp.w12"),
    ("mlp.weights_out", "mlp.w3"),
]:
    for _p in ("weight", "bias"):
        _HF_BLOCK[f"{_hf}.{_p}"] = f"{_official}.{_p}"
_OFFICIAL_BLOCK = {v: k for k, v in _HF_BLOCK.items()}
_HF_TOP = {
    "embeddings.cls_token": "cls_token",
    "embeddings.mask_token": "mask_token",
    "embeddings.position_embeddings": "pos_embed",
    "embeddings.register_tokens": "register_tokens",
    "embeddings.patch_embeddings.projection.weight": "patch_embed.proj.weight",
    "embeddings.patch_embeddings.projection.bias": "patch_embed.proj.bias",
    "layernorm.weight": "norm.weight",
    "layernorm.bias": "norm.bias",
}
_QKV = ("query", "key", "value")


class WeightsError(ValueError):
    """A weights file does not match the backbone (missing, unexpected or mis-shaped keys)."""


def official_url(name: str) -> str:
    """URL of the official checkpoint of a backbone name such as ``dinov2_vitl14_reg``."""
    base = name.removesuffix("_reg")
    full = f"{base}_reg4" if name.endswith("_reg") else base
    return f"{BASE_URL}/{base}/{full}_pretrain.pth"


def is_hf_state_dict(state: dict[str, torch.Tensor]) -> bool:
    """True when the keys are Hugging Face ``Dinov2Model`` names."""
    return any(k.startswith(("embeddings.", "encoder.layer.")) for k in state)


def hf_to_official(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Rename a Hugging Face DINOv2 state dict to official keys (q/k/v concatenated).

    Keys that match no rule are kept unchanged, so the strict load reports them.
    """
    out: dict[str, torch.Tensor] = {}
    qkv: dict[tuple[str, str], dict[str, torch.Tensor]] = {}
    for key, value in state.items():
        if key in _HF_TOP:
            out[_HF_TOP[key]] = value
            continue
        m = re.fullmatch(r"encoder\.layer\.(\d+)\.(.+)", key)
        if m is None:
            out[key] = value
            continue
        idx, inner = m.groups()
        qm = re.fullmatch(r"attention\.attention\.(query|key|value)\.(weight|bias)", inner)
        if qm is not None:
            qkv.setdefault((idx, qm.group(2)), {})[qm.group(1)] = value
        elif inner in _HF_BLOCK:
            out[f"blocks.{idx}.{_HF_BLOCK[inner]}"] = value
        else:
            out[key] = value
    for (idx, kind), parts in qkv.items():
        if set(parts) != set(_QKV):
            missing = sorted(set(_QKV) - set(parts))
            raise WeightsError(
                f"Hugging Face block {idx}: attention {kind} lacks {missing}; "
                "the file is incomplete, download it again"
            )
        out[f"blocks.{idx}.attn.qkv.{kind}"] = torch.cat([parts[n] for n in _QKV], dim=0)
    return out


def official_to_hf(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Inverse of `hf_to_official`: official keys -> Hugging Face ``Dinov2Model`` keys."""
    top = {v: k for k, v in _HF_TOP.items()}
    out: dict[str, torch.Tensor] = {}
    for key, value in state.items():
        if key in top:
            out[top[key]] = value
            continue
        m = re.fullmatch(r"blocks\.(\d+)\.(.+)", key)
        if m is None:
            out[key] = value
            continue
        idx, rest = m.groups()
        if rest.startswith("attn.qkv."):
            kind = rest.removeprefix("attn.qkv.")
            for name, part in zip(_QKV, value.chunk(3, dim=0), strict=True):
                out[f"encoder.layer.{idx}.attention.attention.{name}.{kind}"] = part.clone()
            continue
        if rest in _OFFICIAL_BLOCK:
            out[f"encoder.layer.{idx}.{_OFFICIAL_BLOCK[rest]}"] = value
        else:
            out[key] = value
    return out


def read_state_dict(path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """Read an official ``.pth`` or a Hugging Face ``.safetensors`` into official keys.

    Raises:
        FileNotFoundError: no such file.
        WeightsError: a folder, an empty, truncated or foreign file, or not a dict of tensors.
    """
    path = Path(path)
    state = read_tensor_file(
        path,
        "weights file",
        WeightsError,
        missing_hint="; pass an existing .pth/.safetensors path, 'official' to download the "
        "official checkpoint, or None for a random init",
    )
    if isinstance(state, dict) and isinstance(state.get("model"), dict):
        state = state["model"]
    if not isinstance(state, dict):
        raise WeightsError(f"{path} holds a {type(state).__name__}, not a state dict")
    bad = [k for k, v in state.items() if not isinstance(k, str) or not torch.is_tensor(v)]
    if bad:
        raise WeightsError(
            f"{path} is not a state dict of tensors: entries {bad[:5]} are not name -> tensor; "
            "pass a DINOv2 weights file (official .pth or Hugging Face model.safetensors)"
        )
    # Heads built on Dinov2Model (e.g. Dinov2ForImageClassification) prefix the backbone.
    if any(k.startswith("dinov2.") for k in state):
        state = {k.removeprefix("dinov2."): v for k, v in state.items() if k.startswith("dinov2.")}
    return hf_to_official(state) if is_hf_state_dict(state) else dict(state)


def load_backbone_state(model: nn.Module, state: dict[str, torch.Tensor], source: str) -> None:
    """Strictly load official-key weights, or raise `WeightsError` listing every mismatch."""
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shapes = sorted(
        f"{k}: file {tuple(state[k].shape)} vs model {tuple(own[k].shape)}"
        for k in set(own) & set(state)
        if state[k].shape != own[k].shape
    )
    if missing or unexpected or shapes:
        lines = [f"weights from {source} do not match the backbone:"]
        if missing:
            lines.append(f"  missing keys ({len(missing)}): {', '.join(missing[:20])}")
        if unexpected:
            lines.append(f"  unexpected keys ({len(unexpected)}): {', '.join(unexpected[:20])}")
        if shapes:
            lines.append(f"  wrong shapes ({len(shapes)}): {'; '.join(shapes[:10])}")
        lines.append("  check that the backbone name (size, _reg) matches the file")
        raise WeightsError("\n".join(lines))
    model.load_state_dict(state, strict=True)


def official_checkpoint_path(name: str) -> Path:
    """Where the official checkpoint of ``name`` lives in the torch hub cache."""
    return Path(torch.hub.get_dir()) / "checkpoints" / official_url(name).rsplit("/", 1)[1]


def download_official(name: str) -> Path:
    """Return the cached official checkpoint, downloading it once (the project's only network use).

    Raises:
        ConnectionError: when offline, naming the URL and where to put the file by hand.
    """
    target = official_checkpoint_path(name)
    if target.is_file():
        return target
    url = official_url(name)
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        torch.hub.download_url_to_file(url, str(target), progress=True)
    except Exception as exc:
        raise ConnectionError(
            f"could not download the official {name} weights from {url} ({exc}). "
            f"Download that file on a connected machine and put it at {target} "
            "(or pass its local path as weights=...)"
        ) from exc
    return target
