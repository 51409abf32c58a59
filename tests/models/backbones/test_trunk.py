"""One ViT trunk for both families: shared blocks and attention, the `Backbone` protocol, and the
block selection of ``get_intermediate_layers``."""

import pytest
import torch

from claravid.models import build_backbone, build_model
from claravid.models.backbones.protocol import Backbone
from claravid.models.backbones.trunk import VisionTransformer
from claravid.models.layers.attention import Attention
from claravid.models.layers.blocks import Block

TINY = {
    "dinov2_vits14_reg": {"embed_dim": 32, "depth": 4, "num_heads": 2, "img_size": 28},
    "dinov3_vitl16_sat": {"embed_dim": 32, "depth": 4, "num_heads": 2},
}


@pytest.mark.parametrize("name", sorted(TINY))
def test_both_families_are_one_trunk_and_a_backbone(name):
    model = build_backbone(name, **TINY[name])
    assert isinstance(model, VisionTransformer) and isinstance(model, Backbone)
    assert all(type(b) is Block and type(b.attn) is Attention for b in model.blocks)
    assert (model.embed_dim, model.n_blocks) == (32, 4)
    prefix = 5  # CLS + 4 registers / storage tokens
    assert model.num_prefix_tokens == prefix
    p = model.patch_size
    x = torch.randn(1, 3, 3 * p, 5 * p)
    with torch.no_grad():
        ((patches, cls),) = model.get_intermediate_layers(x, [2], return_class_token=True)
    assert patches.shape == (1, 15, 32) and cls.shape == (1, 32)


def test_block_indices_are_each_given_once():
    model = build_backbone("dinov3_vitl16_sat", **TINY["dinov3_vitl16_sat"])
    x = torch.randn(1, 3, 32, 48)
    with pytest.raises(ValueError, match=r"block indices \[1, 3, 1\] repeat 1: give each block"):
        model.get_intermediate_layers(x, [1, 3, 1])
    with torch.no_grad():  # any order: outputs come in block order, as in the official code
        a = model.get_intermediate_layers(x, [3, 1])
        b = model.get_intermediate_layers(x, [1, 3])
    assert all(torch.equal(u, v) for u, v in zip(a, b, strict=True))


def test_a_segmenter_with_a_repeated_tap_is_refused_when_built():
    """It used to fail at the first forward, with zip()'s own message."""
    with pytest.raises(ValueError, match=r"block indices \[0, 1, 1, 3\] repeat 1"):
        build_model(
            "dinov2_vits14_reg",
            num_classes=3,
            layers=[0, 1, 1, 3],
            features=8,
            out_channels=[8, 8, 8, 8],
            backbone_kwargs=TINY["dinov2_vits14_reg"],
        )
