"""DINOv3's RoPE against values computed here by hand from the published formula."""

import math

import pytest
import torch

from claravid.models.layers.rope import (
    RopePositionEmbedding,
    check_periods,
    rope_apply,
    rotate_half,
)


def _angles_by_hand(rows: int, cols: int, head_dim: int) -> list[list[float]]:
    """Per token (row-major), the head_dim angles: 2 pi c / period for y, then x, tiled twice."""
    periods = [100.0 ** (2 * j / (head_dim / 2)) for j in range(head_dim // 4)]
    out = []
    for i in range(rows):
        for j in range(cols):
            y = 2 * (i + 0.5) / rows - 1
            x = 2 * (j + 0.5) / cols - 1
            half = [2 * math.pi * y / p for p in periods] + [2 * math.pi * x / p for p in periods]
            out.append(half + half)
    return out


def test_periods_of_a_head_of_8():
    # d = 8: two periods, 100 ** 0 and 100 ** (2 / 4).
    torch.testing.assert_close(RopePositionEmbedding(8).periods, torch.tensor([1.0, 10.0]))


def test_angles_of_a_2x3_grid():
    sin, cos = RopePositionEmbedding(8)(2, 3)
    want = torch.tensor(_angles_by_hand(2, 3, 8), dtype=torch.float64)
    assert sin.shape == cos.shape == (6, 8) and sin.dtype == cos.dtype == torch.float32
    torch.testing.assert_close(sin.double(), want.sin(), atol=1e-6, rtol=0)
    torch.testing.assert_close(cos.double(), want.cos(), atol=1e-6, rtol=0)
    # Token (row 0, column 2): y = 2 * 0.25 - 1 = -0.5, x = 2 * 5/6 - 1 = 2/3.
    first_of_row_0_col_2 = [-math.pi, -math.pi / 10, 4 * math.pi / 3, 4 * math.pi / 30]
    torch.testing.assert_close(
        sin[2, :4].double(), torch.tensor(first_of_row_0_col_2).sin().double(), atol=1e-6, rtol=0
    )


def test_rotation_turns_each_channel_pair_by_its_angle():
    """Channel k and k + d/2 form a pair rotated by angle k: [a, b] -> [a cos - b sin, ...]."""
    sin, cos = RopePositionEmbedding(8)(2, 3)
    angles = _angles_by_hand(2, 3, 8)
    x = torch.randn(1, 1, 6, 8, generator=torch.Generator().manual_seed(0))
    got = rope_apply(x, sin, cos)
    for t in range(6):
        for k in range(4):
            a, b = x[0, 0, t, k].item(), x[0, 0, t, k + 4].item()
            c, s = math.cos(angles[t][k]), math.sin(angles[t][k])
            assert got[0, 0, t, k].item() == pytest.approx(a * c - b * s, abs=1e-5)
            assert got[0, 0, t, k + 4].item() == pytest.approx(b * c + a * s, abs=1e-5)
    assert torch.equal(
        rotate_half(torch.tensor([1.0, 2.0, 3.0, 4.0])), torch.tensor([-3.0, -4, 1, 2])
    )


def test_float32_under_autocast_and_in_a_bfloat16_model():
    rope = RopePositionEmbedding(16)
    want = rope(3, 5)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        under = rope(3, 5)
    assert all(t.dtype == torch.float32 for t in under)
    torch.testing.assert_close(under, want, atol=0, rtol=0)
    rope.to(torch.bfloat16)  # a cast keeps the periods float32 (not rounded to 8 bits)
    assert rope.periods.dtype == torch.float32
    assert rope.periods[1].item() == pytest.approx(100.0**0.25, abs=1e-6)  # bfloat16: 3.15625
    cast = rope(3, 5)
    assert all(t.dtype == torch.float32 for t in cast)
    torch.testing.assert_close(cast, want, atol=0, rtol=0)
    # Rotating bfloat16 queries happens in float32 and returns bfloat16.
    q = torch.randn(1, 2, 15, 16).to(torch.bfloat16)
    rotated = rope_apply(q, *want)
    assert rotated.dtype == torch.bfloat16
    torch.testing.assert_close(rotated, rope_apply(q.float(), *want).to(torch.bfloat16))


def test_frozen_grid_gives_the_same_values_and_other_grids_still_work():
    rope = RopePositionEmbedding(16)
    want_35, want_44 = rope(3, 5), rope(4, 4)
    rope.freeze(3, 5)
    torch.testing.assert_close(rope(3, 5), want_35, atol=0, rtol=0)
    torch.testing.assert_close(rope(4, 4), want_44, atol=0, rtol=0)
    rope.freeze(None)
    assert rope._frozen is None


def test_head_width_must_split_in_four():
    with pytest.raises(ValueError, match="divisible by 4"):
        RopePositionEmbedding(10)


def test_stored_periods_of_the_model_s_base_pass_within_a_bfloat16_step():
    # d = 16, base 100: 100 ** (k / 4) = 1, 3.1623, 10, 31.623; bfloat16 keeps 8 significant
    # bits, so 3.1623 is stored as 3.15625 (0.2 % off) and 31.623 as 31.625.
    check_periods(torch.tensor([1.0, 3.15625, 10.0, 31.625], dtype=torch.bfloat16), 16, 100.0)
    check_periods(torch.tensor([1.0, 3.1623, 10.0]), 16, 100.0)  # another shape: the load's


def test_stored_periods_of_another_base_are_refused_naming_the_base_they_fit():
    # base 10000: 10000 ** (k / 4) = 1, 10, 100, 1000; the last gives 1000 ** (16 / 12) = 1e4.
    with pytest.raises(ValueError, match=r"differ from base 100 .* \(they fit base 1e\+04\)"):
        check_periods(torch.tensor([1.0, 10.0, 100.0, 1000.0]), 16, 100.0)
    # One period 1 % off is more than a bfloat16 step.
    with pytest.raises(ValueError, match=r"rope_embed.periods \[1.0, 3.19"):
        check_periods(torch.tensor([1.0, 3.194, 10.0, 31.623]), 16, 100.0)
