"""The three heads satisfy the `Head` protocol the segmenter and the export rely on, and the
segmenter refuses a head that does not."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from claravid.models import build_model
from claravid.models.heads.dpt import DPTHead
from claravid.models.heads.linear import LinearHead
from claravid.models.heads.protocol import Head
from claravid.models.heads.upernet import UperNetHead
from claravid.models.segmenter import Segmenter
from tests.tiny import MODEL, VIT

D, K = 16, 3
HEADS = {
    "dpt": lambda: DPTHead(D, K, features=8, out_channels=(8, 8, 8, 8)),
    "linear": lambda: LinearHead(D, K, 2, use_cls=True),
    "upernet": lambda: UperNetHead(D, K, channels=8),
}


@pytest.mark.parametrize("name", sorted(HEADS))
def test_each_head_is_a_head_and_gives_k_logits_at_the_output_size(name):
    head = HEADS[name]().eval()
    assert isinstance(head, Head) and isinstance(head, nn.Module)
    assert head.num_classes == K
    # A 3 x 5 grid (not square), 4 tapped blocks of (tokens, CLS) pairs, output 40 x 66.
    taps = 2 if name == "linear" else 4
    feats = [(torch.randn(2, 15, D), torch.randn(2, D)) for _ in range(taps)]
    with torch.no_grad():
        out = head(feats, 3, 5, (40, 66))
    assert out.shape == (2, K, 40, 66)
    assert any(p.requires_grad for p in head.parameters())


@pytest.mark.parametrize("head", ["dpt", "linear", "upernet"])
def test_build_model_gives_a_head_the_protocol_describes(head):
    extra = {"layers": [3]} if head == "linear" else {"layers": [0, 1, 2, 3], "features": 8}
    model = build_model("dinov2_vits14", K, head=head, backbone_kwargs=VIT, **extra)
    assert isinstance(model.head, Head)


class NoNumClasses(nn.Module):
    def forward(self, feats, grid_h, grid_w, out_size):
        return torch.zeros(1)


class NotAModule:
    num_classes = K

    def forward(self, feats, grid_h, grid_w, out_size):
        return torch.zeros(1)

    __call__ = forward

    def parameters(self, recurse=True):
        return iter(())

    def train(self, mode=True):
        return self


@pytest.mark.parametrize("bad", [NoNumClasses, NotAModule])
def test_the_segmenter_refuses_what_is_not_a_head(bad):
    backbone = build_model("dinov2_vits14", num_classes=K, **MODEL).backbone
    with pytest.raises(TypeError, match=rf"head must be an nn.Module .*got {bad.__name__}"):
        Segmenter(backbone, bad(), [3])
