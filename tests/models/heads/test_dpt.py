"""The DPT head against an independent restatement (docs/models.md) in functional torch ops.

The reference below reads only the head's weights (by name) and applies the recipe step by step
with ``torch.nn.functional``; it shares no code with ``models/heads/dpt.py``. A plausible slip in
the
decoder (nearest instead of bilinear upsampling, ``align_corners`` flipped, a subtraction in the
fusion, a missing residual, the wrong resize of a level) changes the logits by far more than the
tolerance.
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from claravid.models import DPTHead

D, FEATURES, OUT = 24, 16, (8, 12, 16, 20)


def reference_dpt(
    w: dict[str, torch.Tensor],
    feats: list[tuple[torch.Tensor, torch.Tensor]],
    grid: tuple[int, int],
    out_size: tuple[int, int],
    use_cls: bool,
) -> torch.Tensor:
    """The DPT head as docs/models.md describes it, literally."""
    gh, gw = grid
    levels = []
    for i, (tokens, cls) in enumerate(feats):
        pre = f"reassemble.{i}."
        if use_cls:  # readout: concat token with CLS, Linear(2D -> D) + GELU
            both = torch.cat([tokens, cls[:, None, :].expand(-1, tokens.shape[1], -1)], dim=-1)
            tokens = F.gelu(F.linear(both, w[pre + "readout.0.weight"], w[pre + "readout.0.bias"]))
        x = tokens.transpose(1, 2).reshape(tokens.shape[0], D, gh, gw)
        x = F.conv2d(x, w[pre + "project.weight"], w[pre + "project.bias"])  # 1x1: D -> out[i]
        resize_w, resize_b = w.get(pre + "resize.weight"), w.get(pre + "resize.bias")
        if i == 0:  # ConvTranspose k4 s4
            x = F.conv_transpose2d(x, resize_w, resize_b, stride=4)
        elif i == 1:  # ConvTranspose k2 s2
            x = F.conv_transpose2d(x, resize_w, resize_b, stride=2)
        elif i == 3:  # Conv k3 s2 p1
            x = F.conv2d(x, resize_w, resize_b, stride=2, padding=1)
        # i == 2: identity
        levels.append(F.conv2d(x, w[f"layer_rn.{i}.weight"], None, padding=1))  # 3x3, no bias

    def rcu(x, pre):  # ReLU, 3x3 conv, ReLU, 3x3 conv, + input
        y = F.conv2d(F.relu(x), w[pre + "conv1.weight"], w[pre + "conv1.bias"], padding=1)
        y = F.conv2d(F.relu(y), w[pre + "conv2.weight"], w[pre + "conv2.bias"], padding=1)
        return x + y

    x = None
    for i in (3, 2, 1, 0):  # coarse to fine
        pre = f"fusion.{i}."
        x = levels[i] if x is None else x + rcu(levels[i], pre + "res1.")  # add the lateral input
        x = rcu(x, pre + "res2.")
        if i > 0:  # bilinear, align_corners=True, to the next (finer) level's size
            x = F.interpolate(x, size=levels[i - 1].shape[-2:], mode="bilinear", align_corners=True)
        x = F.conv2d(x, w[pre + "out_conv.weight"], w[pre + "out_conv.bias"])  # 1x1
    # Segmentation head at the finest level: 3x3 conv + ReLU + 1x1 conv to the classes.
    x = F.relu(F.conv2d(x, w["head.0.weight"], w["head.0.bias"], padding=1))
    logits = F.conv2d(x, w["head.2.weight"], w["head.2.bias"])
    # The published DPT description leaves the mode of this last upsampling open; the head
    # documents bilinear without align_corners (torch's default for images).
    return F.interpolate(logits, size=out_size, mode="bilinear", align_corners=False)


def _head_and_inputs(use_cls: bool, grid: tuple[int, int], seed: int = 0):
    torch.manual_seed(seed)
    head = DPTHead(D, num_classes=5, features=FEATURES, out_channels=OUT, use_cls=use_cls).eval()
    with torch.no_grad():  # weights well away from init so that every term matters
        for p in head.parameters():
            p.copy_(0.3 * torch.randn_like(p))
    n = grid[0] * grid[1]
    feats = [(torch.randn(2, n, D), torch.randn(2, D)) for _ in range(4)]
    return head, feats


@pytest.mark.parametrize(
    ("use_cls", "grid", "out_size"),
    [(False, (3, 4), (42, 56)), (True, (5, 3), (70, 42)), (False, (4, 4), (50, 61))],
)
def test_head_matches_the_format_recipe(use_cls, grid, out_size):
    head, feats = _head_and_inputs(use_cls, grid)
    with torch.no_grad():
        got = head(feats, *grid, out_size)
        expected = reference_dpt(head.state_dict(), feats, grid, out_size, use_cls)
    assert got.shape == (2, 5, *out_size)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)
    assert expected.std() > 0.1  # logits that actually vary: a real comparison
