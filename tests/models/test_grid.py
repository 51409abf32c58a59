"""The patch grid, by hand: natural sizes, the nearest valid sizes, and what a message says."""

import pytest

from claravid.models.grid import (
    PAPER_WINDOW,
    check_image_size,
    natural_size,
    nearest_multiples,
    nearest_sizes,
    padded_size,
    patch_fix,
)


def test_natural_size_and_nearest_multiples_by_hand():
    assert PAPER_WINDOW == natural_size(14) == 630  # 45 x 14, the paper's window
    assert natural_size(16) == 640  # 40 x 16: the smallest multiple of 16 covering 630
    assert natural_size(8) == 632  # 79 x 8
    assert nearest_multiples(640, 14) == (630, 644)
    assert nearest_multiples(630, 16) == (624, 640)
    assert nearest_multiples(630, 14) == (630, 630)
    assert nearest_multiples(10, 14) == (14, 28)  # below one patch: the two smallest


def test_a_non_square_size_keeps_its_sides_apart():
    # 30 high, 70 wide with patches of 16: height 16 or 32, width 64 or 80.
    assert nearest_sizes(30, 70, 16) == ((16, 64), (32, 80))
    assert nearest_sizes(32, 70, 16) == ((32, 64), (32, 80))  # the height fits: it stays
    # Said width x height, as the size flags take them.
    assert patch_fix(30, 70, 16, "--size ") == "use --size 64x16 or --size 80x32"
    assert padded_size(30, 70, 16) == (32, 80)
    assert padded_size(32, 64, 16) == (32, 64)


def test_check_image_size_says_the_padded_and_the_cropped_size():
    check_image_size(28, 42, 14)
    with pytest.raises(ValueError, match=r"input size 50x57 .* pad or resize it to 56x70 \(or crop "
                       r"to 42x56\)"):  # fmt: skip
        check_image_size(50, 57, 14)
    with pytest.raises(ValueError, match=r"pad or resize it to 14x28$"):  # nothing to crop to
        check_image_size(10, 20, 14)
    with pytest.raises(ValueError, match="input size 0x28 is empty"):
        check_image_size(0, 28, 14)
