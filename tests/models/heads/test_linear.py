"""The linear head against DINOv3's linear protocol restated in functional torch ops.

The reference reads only the head's weights (by name) and applies the official order: tokens as
a map on the patch grid (CLS concatenated per block when asked, blocks concatenated),
channel dropout, BatchNorm, 1x1 convolution, bilinear upsampling without ``align_corners``. The
segmenter test checks what the head reads: the last block, through the backbone's final norm
(an independent DINOv2 forward, ``tests/models/backbones/reference.py``).
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from claravid.models import build_model
from claravid.models.heads.linear import LinearHead
from tests.models.backbones.reference import random_official_state, reference_layers

D, K = 24, 5


def reference_linear(w, feats, grid, out_size, use_cls, training=False):
    """The official linear segmentation, literally (training: batch statistics, dropout 0.1)."""
    gh, gw = grid
    maps = []
    for tokens, cls in feats:
        if use_cls:
            tokens = torch.cat([tokens, cls[:, None, :].expand_as(tokens)], dim=-1)
        maps.append(tokens.permute(0, 2, 1).reshape(tokens.shape[0], -1, gh, gw))
    x = torch.cat(maps, dim=1)
    x = F.dropout2d(x, 0.1, training=training)  # before the BatchNorm, as the official head
    if training:
        mean, var = x.mean((0, 2, 3)), x.var((0, 2, 3), unbiased=False)
    else:
        mean, var = w["bn.running_mean"], w["bn.running_var"]
    x = (x - mean[:, None, None]) / torch.sqrt(var[:, None, None] + 1e-5)
    x = x * w["bn.weight"][:, None, None] + w["bn.bias"][:, None, None]
    logits = F.conv2d(x, w["conv.weight"], w["conv.bias"])
    return F.interpolate(logits, size=out_size, mode="bilinear", align_corners=False)


def _head(num_layers, use_cls, seed=0):
    torch.manual_seed(seed)
    head = LinearHead(D, K, num_layers=num_layers, use_cls=use_cls)
    with torch.no_grad():  # weights and statistics well away from their init
        for p in head.parameters():
            p.copy_(0.3 * torch.randn_like(p))
        head.bn.running_mean.normal_()
        head.bn.running_var.uniform_(0.5, 2.0)
    return head


@pytest.mark.parametrize(
    ("num_layers", "use_cls", "grid", "out_size"),
    [(1, False, (3, 5), (48, 80)), (1, True, (4, 3), (56, 42)), (4, False, (5, 2), (61, 33))],
)
def test_eval_equals_the_official_recipe(num_layers, use_cls, grid, out_size):
    head = _head(num_layers, use_cls).eval()
    n = grid[0] * grid[1]
    feats = [(torch.randn(2, n, D), torch.randn(2, D)) for _ in range(num_layers)]
    with torch.no_grad():
        got = head(feats, *grid, out_size)
    expected = reference_linear(head.state_dict(), feats, grid, out_size, use_cls)
    assert got.shape == (2, K, *out_size)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)


def test_training_drops_channels_before_the_batchnorm():
    """In training the order matters: BatchNorm statistics of the dropped features (the
    official order) differ from dropping after normalising. Same seed, same channel mask."""
    head = _head(1, False).train()
    feats = [(torch.randn(4, 15, D), torch.randn(4, D))]
    torch.manual_seed(7)
    got = head(feats, 3, 5, (48, 80))
    torch.manual_seed(7)
    expected = reference_linear(head.state_dict(), feats, (3, 5), (48, 80), False, training=True)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    assert head.dropout.p == 0.1


def test_the_official_initialisation():
    head = LinearHead(1024, 19)
    assert head.bn.num_features == 1024 and head.conv.kernel_size == (1, 1)
    assert abs(float(head.conv.weight.detach().std()) - 0.01) < 1e-3 and not head.conv.bias.any()
    assert LinearHead(1024, 19, num_layers=4, use_cls=True).bn.num_features == 8192


def test_the_segmenter_reads_the_last_block_through_the_final_norm():
    torch.manual_seed(0)
    tiny = {"embed_dim": 32, "depth": 4, "num_heads": 2, "img_size": 56}
    model = build_model("dinov2_vits14_reg", num_classes=K, head="linear", backbone_kwargs=tiny)
    assert model.layers == (3,) and model.num_classes == K
    assert model.model_args["head"] == "linear" and model.model_args["layers"] == [3]
    state = random_official_state(model.backbone, seed=3)
    model.backbone.load_state_dict(state)
    captured = {}
    model.head.register_forward_pre_hook(lambda module, args: captured.update(feats=args[0]))
    x = torch.randn(1, 3, 42, 70)  # a 3 x 5 grid
    model.eval()(x)
    ((tokens, cls),) = captured["feats"]
    ((ref_tokens, ref_cls),) = reference_layers(state, x, 2, [3], registers=True, norm=True)
    torch.testing.assert_close(tokens, ref_tokens, atol=1e-4, rtol=0)
    torch.testing.assert_close(cls, ref_cls, atol=1e-4, rtol=0)
