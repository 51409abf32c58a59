"""Weights files as the tests write them: a tiny DINOv3 backbone's state as its released file
holds it, a state dict saved the way its suffix says, and the DINOv2 Hugging Face names through
the weights room's own table (`claravid.models.weights.dinov2.HUGGING_FACE`)."""

from __future__ import annotations

from pathlib import Path

import torch
from safetensors.torch import save_file

from claravid.models import build_backbone
from claravid.models.weights import dinov2
from claravid.models.weights.formats import State, from_official, to_official
from tests.models.weights.official_v3 import released_v3_state
from tests.tiny import TINY_V3


def released_state(name: str, seed: int, **extra: object) -> State:
    """The state dict of the tiny (`TINY_V3`, with ``extra``) DINOv3 backbone ``name``, random
    weights from ``seed``, as the released official file of that model holds it (bfloat16 RoPE
    periods for the distilled models)."""
    return released_v3_state(build_backbone(name, **{**TINY_V3, **extra}), name, seed)


def saved(state: dict[str, torch.Tensor], path: Path) -> Path:
    """``state`` saved as ``path`` (returned): safetensors for ``.safetensors``, ``torch.save``
    otherwise (parent folders made)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".safetensors":
        save_file({k: v.contiguous() for k, v in state.items()}, str(path))
    else:
        torch.save(state, path)
    return path


def dinov2_to_hugging_face(state: State) -> State:
    """Official DINOv2 keys -> Hugging Face ``Dinov2Model`` keys (q/k/v split; the giant
    model's SwiGLU named as Hugging Face names it)."""
    gated = any(".mlp.w12." in k for k in state)
    return from_official(dict(state), dinov2.HUGGING_FACE, "swiglu" if gated else "mlp")


def dinov2_from_hugging_face(state: State) -> State:
    """Hugging Face ``Dinov2Model`` keys -> official ones (q/k/v joined); keys no rule knows are
    kept, as the loader keeps them for its strict load to report."""
    return to_official(dict(state), dinov2.HUGGING_FACE)
