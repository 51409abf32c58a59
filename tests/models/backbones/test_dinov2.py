"""The ViT backbone against a plain reference forward written from the official semantics."""

import pytest
import torch
import torch.nn.functional as F

from claravid.models import BACKBONES, build_backbone
from claravid.models.backbones.dinov2 import bicubic_matrix, swiglu_hidden
from tests.models.backbones.reference import random_official_state, reference_layers
from tests.tiny import VIT_3 as TINY  # native grid 4x4


def _tiny(name: str, **extra) -> tuple[torch.nn.Module, dict]:
    model = build_backbone(name, **{**TINY, **extra}).eval()
    state = random_official_state(model)
    model.load_state_dict(state)
    return model, state


@pytest.mark.parametrize("name", ["dinov2_vits14", "dinov2_vits14_reg", "dinov2_vitg14"])
@pytest.mark.parametrize("size", [(56, 56), (42, 70), (98, 84)])
def test_intermediate_layers_match_reference(name, size):
    model, state = _tiny(name)
    x = torch.randn(2, 3, *size, generator=torch.Generator().manual_seed(1))
    got = model.get_intermediate_layers(x, [0, 2], return_class_token=True)
    want = reference_layers(state, x, 2, [0, 2], registers=name.endswith("_reg"))
    assert len(got) == 2
    for (patches, cls), (ref_patches, ref_cls) in zip(got, want, strict=True):
        assert patches.shape == (2, (size[0] // 14) * (size[1] // 14), 32)
        torch.testing.assert_close(patches, ref_patches, atol=1e-4, rtol=0)
        torch.testing.assert_close(cls, ref_cls, atol=1e-4, rtol=0)


def test_intermediate_layers_options():
    model, state = _tiny("dinov2_vits14_reg")
    x = torch.randn(1, 3, 42, 70)
    last2 = model.get_intermediate_layers(x, 2, norm=False)
    ref = reference_layers(state, x, 2, [1, 2], registers=True, norm=False)
    torch.testing.assert_close(last2[0], ref[0][0], atol=1e-4, rtol=0)
    torch.testing.assert_close(last2[1], ref[1][0], atol=1e-4, rtol=0)
    (grid,) = model.get_intermediate_layers(x, [1], reshape=True)
    assert grid.shape == (1, 32, 3, 5)
    # reshape lays tokens out row-major: token r*5+c is grid[..., r, c]
    (flat,) = model.get_intermediate_layers(x, [1])
    torch.testing.assert_close(grid[0, :, 1, 3], flat[0, 1 * 5 + 3])
    with pytest.raises(ValueError, match=r"block indices \[5\] must be in \[0, 2\]"):
        model.get_intermediate_layers(x, [5])


def test_odd_size_suggests_padded_size():
    model, _ = _tiny("dinov2_vits14")
    with pytest.raises(
        ValueError, match=r"not a multiple of the patch size 14.*pad or resize it to 56x70"
    ):
        model(torch.randn(1, 3, 50, 57))


def test_patch_size_is_read_from_the_model():
    model = build_backbone("dinov2_vits14", **{**TINY, "patch_size": 8, "img_size": 32}).eval()
    out = model.get_intermediate_layers(torch.randn(1, 3, 40, 24), 1, reshape=True)[0]
    assert out.shape == (1, 32, 5, 3)
    with pytest.raises(ValueError, match=r"patch size 8.*48x24"):
        model(torch.randn(1, 3, 41, 24))


@pytest.mark.parametrize("grid", [3, 5, 7, 45, 36])
def test_bicubic_matrix_equals_interpolate(grid):
    m = 37 if grid > 10 else 4
    x = torch.randn(1, 6, m, m)
    scale = (grid + 0.1) / m
    want = F.interpolate(x, scale_factor=(scale, scale), mode="bicubic")
    a = bicubic_matrix(grid, m, 0.1)
    # F.interpolate itself is within ~1e-5 of a float64 resize at these sizes.
    torch.testing.assert_close(a @ x @ a.T, want, atol=2e-5, rtol=0)


def test_official_shapes_and_parameter_counts():
    expected = {  # millions, official models (pos_embed at 518 included)
        "dinov2_vits14": 22.06,
        "dinov2_vitb14": 86.58,
        "dinov2_vitl14": 304.37,
        "dinov2_vitg14": 1136.48,
    }
    for name in [n for n, spec in BACKBONES.items() if spec.family == "dinov2"]:
        with torch.device("meta"):
            model = build_backbone(name)
        state = model.state_dict()
        d = model.embed_dim
        assert state["pos_embed"].shape == (1, 1370, d)
        assert state["mask_token"].shape == (1, d)
        assert ("register_tokens" in state) == name.endswith("_reg")
        count = sum(v.numel() for k, v in state.items() if k != "register_tokens") / 1e6
        assert count == pytest.approx(expected[name.removesuffix("_reg")], abs=0.01)
    with torch.device("meta"):
        giant = build_backbone("dinov2_vitg14_reg").state_dict()
    assert giant["blocks.39.mlp.w12.weight"].shape == (8192, 1536)
    assert giant["blocks.39.mlp.w3.weight"].shape == (1536, 4096)
    assert swiglu_hidden(1536) == 4096


def test_unknown_backbone_and_argument():
    with pytest.raises(ValueError, match=r"unknown backbone 'vit_l'.*dinov2_vitl14"):
        build_backbone("vit_l")
    with pytest.raises(ValueError, match=r"unknown backbone arguments \['depthh'\]"):
        build_backbone("dinov2_vits14", depthh=3)
