"""UperNet against `transformers`' ``UperNetHead`` (an independent implementation of
mmsegmentation's ``UPerHead``), and the ViT pyramid against a functional restatement.

Weights are copied by name into the transformers head; the inputs are non-square pyramids
(including odd sizes, where pooling cells overlap), so a level or an axis taken in the wrong
order, a missing top-down sum or a wrong resize changes the logits by far more than 1e-5.
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from claravid.models import build_model
from claravid.models.heads.upernet import UperNetHead

upernet = pytest.importorskip("transformers.models.upernet.modeling_upernet")

D, C, K = 24, 16, 5


def assert_close(got, expected):
    """Equal to float32 rounding: our pooling averages by matrix products (for ONNX), torch's
    adaptive pooling sums in another order, ~4e-7 of the logits' scale apart."""
    assert got.shape == expected.shape
    scale = float(expected.detach().abs().max())
    torch.testing.assert_close(got, expected, atol=2e-6 * scale, rtol=0)


def _randomise(module, seed=0):
    """Every weight and BatchNorm statistic away from its init (so each term matters)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, t in module.state_dict().items():
            if name.endswith("num_batches_tracked"):
                continue
            noise = torch.randn(t.shape, generator=g)
            if name.endswith("running_var"):
                t.copy_(0.5 + noise.abs())
            elif name.endswith("bn.weight") or name.endswith(".1.weight"):
                t.copy_(1.0 + 0.2 * noise)
            else:
                t.copy_(0.3 * noise)
    return module


def hf_name(ours: str) -> str:
    """Our UperNet parameter name -> transformers' (mmsegmentation's layout, other spellings)."""
    name = ours.replace(".bn.", ".batch_norm.")
    if name.startswith("psp_modules."):  # transformers keeps the pooling as stage "0"
        _, i, rest = name.split(".", 2)
        name = f"psp_modules.{i}.1.{rest.removeprefix('conv.')}"
    return name


def _pair(seed=0):
    ours = _randomise(UperNetHead(D, K, channels=C), seed)
    config = upernet.UperNetConfig(hidden_size=C, pool_scales=[1, 2, 3, 6], num_labels=K)
    theirs = upernet.UperNetHead(config, in_channels=[D] * 4)
    state = {hf_name(k): v for k, v in ours.state_dict().items() if not k.startswith("neck.")}
    assert set(state) == set(theirs.state_dict())  # every weight has its counterpart
    theirs.load_state_dict(state)
    return ours, theirs


@pytest.mark.parametrize("grid", [(5, 7), (4, 4), (3, 8)])
def test_decode_equals_transformers_upernet_head(grid):
    ours, theirs = _pair()
    h, w = grid
    levels = [torch.randn(2, D, 4 * h, 4 * w), torch.randn(2, D, 2 * h, 2 * w),
              torch.randn(2, D, h, w), torch.randn(2, D, h // 2, w // 2)]  # fmt: skip
    with torch.no_grad():
        expected = theirs.eval()(levels)
        got = ours.eval().decode(levels)
    assert got.shape == (2, K, 4 * h, 4 * w)
    assert_close(got, expected)


def test_training_mode_equals_transformers_but_for_the_dropout():
    """Batch statistics and running-statistic updates too (the dropout before the classifier,
    mmsegmentation's, is the one thing transformers' head leaves out)."""
    ours, theirs = _pair(seed=1)
    ours.dropout = torch.nn.Identity()
    levels = [torch.randn(3, D, 20, 28), torch.randn(3, D, 10, 14), torch.randn(3, D, 5, 7),
              torch.randn(3, D, 2, 3)]  # fmt: skip
    assert_close(ours.train().decode(levels), theirs.train()(levels))
    for name, value in theirs.state_dict().items():
        if "running" in name:
            ours_name = next(k for k in ours.state_dict() if hf_name(k) == name)
            torch.testing.assert_close(ours.state_dict()[ours_name], value)


def reference_pyramid(w, maps):
    """mmsegmentation's Feature2Pyramid on four maps: x4 (deconv, BN, GELU, deconv), x2
    (deconv), identity, 2x2 max-pool."""

    def bn(x, pre):
        mean, var = w[pre + "running_mean"], w[pre + "running_var"]
        x = (x - mean[:, None, None]) / torch.sqrt(var[:, None, None] + 1e-5)
        return x * w[pre + "weight"][:, None, None] + w[pre + "bias"][:, None, None]

    up4 = F.conv_transpose2d(maps[0], w["neck.upsample_4x.0.weight"], w["neck.upsample_4x.0.bias"],
                             stride=2)  # fmt: skip
    up4 = F.gelu(bn(up4, "neck.upsample_4x.1."))
    up4 = F.conv_transpose2d(up4, w["neck.upsample_4x.3.weight"], w["neck.upsample_4x.3.bias"],
                             stride=2)  # fmt: skip
    up2 = F.conv_transpose2d(maps[1], w["neck.upsample_2x.weight"], w["neck.upsample_2x.bias"],
                             stride=2)  # fmt: skip
    return [up4, up2, maps[2], F.max_pool2d(maps[3], 2, 2)]


def test_whole_head_on_tokens_of_a_non_square_odd_grid():
    """Tokens of a 5 x 7 grid -> pyramid 20x28, 10x14, 5x7, 2x3 -> transformers' UperNet ->
    logits upsampled bilinearly to the input size."""
    ours, theirs = _pair(seed=2)
    grid, out_size = (5, 7), (80, 112)
    feats = [(torch.randn(2, 35, D), torch.randn(2, D)) for _ in range(4)]
    maps = [t.permute(0, 2, 1).reshape(2, D, *grid) for t, _ in feats]
    with torch.no_grad():
        got = ours.eval()(feats, *grid, out_size)
        levels = reference_pyramid(ours.state_dict(), maps)
        assert [tuple(x.shape[-2:]) for x in levels] == [(20, 28), (10, 14), (5, 7), (2, 3)]
        expected = F.interpolate(theirs.eval()(levels), size=out_size, mode="bilinear")
    assert_close(got, expected)


def test_segmenter_defaults_for_dinov3_vitl16():
    with torch.device("meta"):
        model = build_model("dinov3_vitl16", num_classes=19, head="upernet")
    assert model.layers == (4, 11, 17, 23)
    assert model.model_args["features"] == 512 and "out_channels" not in model.model_args
    head = model.head
    assert head.classifier.in_channels == 512 and head.num_classes == 19
    assert head.bottleneck.conv.in_channels == 1024 + 4 * 512
    assert head.lateral_convs[0].conv.in_channels == 1024
    assert [s.scale for s in head.psp_modules] == [1, 2, 3, 6]


def test_the_classifier_starts_small_with_a_zero_bias():
    """As the official heads: N(0, 0.01²) weights (2,560 of them: the std is within 10 %)."""
    torch.manual_seed(0)
    head = UperNetHead(32, 10, channels=256)
    assert head.classifier.kernel_size == (1, 1)
    assert abs(float(head.classifier.weight.detach().std()) - 0.01) < 1e-3
    assert not head.classifier.bias.any()


def test_an_input_under_two_patches_a_side_is_refused_in_one_line():
    tiny = {"embed_dim": 32, "depth": 4, "num_heads": 2}
    model = build_model("dinov3_vits16", 3, head="upernet", layers=[0, 1, 2, 3], features=8,
                        backbone_kwargs=tiny).eval()  # fmt: skip
    assert model(torch.randn(1, 3, 32, 48)).shape == (1, 3, 32, 48)  # 2 x 3 patches: the least
    with pytest.raises(
        ValueError, match=r"at least 2 x 2 patches \(32x32 px at patch size 16.* got 48x16"
    ):
        model(torch.randn(1, 3, 16, 48))
