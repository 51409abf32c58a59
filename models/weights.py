"""Backbone weights files: reading, which family a file belongs to, strict loading, and the
DINOv2 key formats and download.

Our parameter names are the official ones, so an official ``.pth`` needs no mapping. A Hugging
Face ``Dinov2Model`` / ``Dinov2WithRegistersModel`` ``model.safetensors`` is renamed key by key,
with its separate query/key/value projections concatenated into ``qkv`` (rows q, k, v). DINOv3's
Hugging Face names and checks are in `claravid.models.weights_v3`; `claravid.models.build`
picks the family's conversion from the backbone's description.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import torch
from torch import nn

from claravid.models.backbones import DINOV3_REQUEST_URL, FAMILIES, BackboneSpec, backbone_spec
from claravid.models.torchfile import read_tensor_file

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
    """A weights file does not match the backbone (missing, unexpected or mis-shaped keys, another
    family, other pre-training data), or cannot be read or fetched."""


def licence_gated(spec: BackboneSpec) -> WeightsError:
    """The one-line error for ``weights="official"`` where the files cannot be downloaded."""
    return WeightsError(
        f"the official {spec.family_name} weights are licence-gated and cannot be downloaded "
        f"here: accept the licence at {DINOV3_REQUEST_URL} (the download URLs come by e-mail), "
        f"fetch {spec.weights.file} and pass its path as weights=... "
        f"(claravid-train: model.weights=PATH)"
    )


def official_url(name: str) -> str:
    """URL of the official checkpoint of a backbone name such as ``dinov2_vitl14_reg``.

    Raises:
        WeightsError: the backbone's weights are licence-gated (DINOv3): there is no public URL.
    """
    spec = backbone_spec(name)
    if spec.weights.url is None:
        raise licence_gated(spec)
    return spec.weights.url


def is_hf_state_dict(state: dict[str, torch.Tensor]) -> bool:
    """True when the keys are Hugging Face ``Dinov2Model`` names (given a DINOv2 file)."""
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


def read_weights_file(path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """Read a ``.pth`` or ``.safetensors`` into a dict of tensors, keys as in the file.

    A training checkpoint's ``{"model": state_dict, ...}`` is unwrapped.

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
            "pass backbone weights (an official .pth or a Hugging Face model.safetensors)"
        )
    return dict(state)


# Keys that only one family's files have, official and Hugging Face spellings. DINOv2: a learned
# positional table, the giant model's fused SwiGLU, transformers' "encoder.layer" (and "dinov2."
# of its task models). DINOv3: storage tokens, the RoPE periods, the masked key bias, and
# transformers' "layer.N" / "model.layer.N" with q/k/v/o projections.
_FAMILY_KEYS: dict[str, re.Pattern[str]] = {
    "dinov2": re.compile(
        r"(dinov2\.)?(pos_embed|embeddings\.position_embeddings|encoder\.layer\..*"
        r"|blocks\.\d+\.mlp\.w12\..*)"
    ),
    "dinov3": re.compile(
        r"(model\.)?(storage_tokens|rope_embed\.periods|local_cls_norm\..*"
        r"|blocks\.\d+\.attn\.qkv\.bias_mask|layer\.\d+\..*)"
    ),
}


def weights_family(state: dict[str, Any]) -> tuple[str, str] | None:
    """(family, a key that shows it) when the keys are one family's only, else None."""
    found = {}
    for family, pattern in _FAMILY_KEYS.items():
        key = next((k for k in sorted(state) if pattern.fullmatch(k)), None)
        if key is not None:
            found[family] = key
    return next(iter(found.items())) if len(found) == 1 else None


def check_family(state: dict[str, Any], spec: BackboneSpec, source: str) -> None:
    """Raise `WeightsError` naming both families when the file is the other family's."""
    found = weights_family(state)
    if found is None or found[0] == spec.family:
        return
    family, key = found
    raise WeightsError(
        f"{source} holds {FAMILIES[family]} weights (it has {key!r}), but {spec.name} is a "
        f"{spec.family_name} backbone: build a {FAMILIES[family]} backbone ({family}_...) for "
        f"this file, or pass {spec.family_name} weights for {spec.name}"
    )


def dinov2_state(
    state: dict[str, torch.Tensor], model: nn.Module, spec: BackboneSpec, source: str
) -> dict[str, torch.Tensor]:
    """A DINOv2 file's tensors under official keys (Hugging Face names renamed)."""
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
        lines.append("  check that the backbone name (size; _reg for DINOv2) matches the file")
        raise WeightsError("\n".join(lines))
    model.load_state_dict(state, strict=True)


def official_checkpoint_path(name: str) -> Path:
    """Where the official checkpoint of ``name`` lives in the torch hub cache."""
    return Path(torch.hub.get_dir()) / "checkpoints" / backbone_spec(name).weights.file


def download_official(name: str) -> Path:
    """Return the cached official checkpoint, downloading it once (the project's only network use).

    Raises:
        WeightsError: the weights are licence-gated (DINOv3): nothing to download.
        ConnectionError: when offline, naming the URL and where to put the file by hand.
    """
    url = official_url(name)
    target = official_checkpoint_path(name)
    if target.is_file():
        return target
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
