"""Joint counts of two byte images against numpy's bincount."""

import numpy as np
import pytest

from claravid.eval.measures.joint_counts import joint_counts as count_pairs


def plain_counts(first, second):
    index = first.astype(np.int64).ravel() * 256 + second.ravel()
    return np.bincount(index, minlength=1 << 16).reshape(256, 256)


def runs(rng, shape, values):
    """Rows of runs of random lengths (1 to 40 pixels), as label images are made of."""
    flat = np.repeat(
        rng.integers(0, values, shape[0] * shape[1]), rng.integers(1, 41, shape[0] * shape[1])
    )
    return flat[: shape[0] * shape[1]].reshape(shape).astype(np.uint8)


@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (17, 45), (64, 129)])
def test_counts_match_bincount_on_runs_and_noise(shape):
    rng = np.random.default_rng(shape[1])
    for first, second in (
        (runs(rng, shape, 4), runs(rng, shape, 3)),  # runs that break in one image only
        (rng.integers(0, 256, shape, dtype=np.uint8), runs(rng, shape, 256)),  # noise
        (np.full(shape, 255, np.uint8), np.full(shape, 7, np.uint8)),  # one run: the whole image
    ):
        got = count_pairs(first, second)
        assert got.dtype == np.int64 and got.shape == (256, 256)
        np.testing.assert_array_equal(got, plain_counts(first, second))


@pytest.mark.parametrize("shape", [(1, 1), (5, 9), (33, 70)])
def test_one_channel_of_an_interleaved_pair_is_counted_in_place(shape):
    rng = np.random.default_rng(shape[0])
    first = runs(rng, shape, 3)
    for second in (
        np.stack([runs(rng, shape, 4), runs(rng, shape, 2)], -1),  # channels break apart
        np.stack([first, np.full(shape, 9, np.uint8)], -1),  # one long run in channel 1
        rng.integers(0, 256, (*shape, 2), dtype=np.uint8),
    ):
        for channel in (0, 1):
            expected = plain_counts(first, np.ascontiguousarray(second[..., channel]))
            np.testing.assert_array_equal(count_pairs(first, second, channel), expected)


def test_an_image_counted_in_bands_adds_up():
    rng = np.random.default_rng(4)
    first, second = runs(rng, (30, 41), 5), np.stack([runs(rng, (30, 41), 3)] * 2, -1)
    total = np.zeros((256, 256), np.int64)
    for band in (slice(0, 7), slice(7, 8), slice(8, 30)):
        assert count_pairs(first[band], second[band], 1, out=total) is total
    np.testing.assert_array_equal(total, plain_counts(first, second[..., 1]))
    with pytest.raises(ValueError, match="C-contiguous int64 256×256"):
        count_pairs(first, second, 1, out=np.zeros((256, 256), np.int32))


def test_a_strided_view_is_counted_as_its_pixels():
    rng = np.random.default_rng(2)
    both = runs(rng, (20, 60), 5)
    first, second = both[:, ::2], both[:, 1::2]  # not contiguous
    np.testing.assert_array_equal(count_pairs(first, second), plain_counts(first, second))


def test_bad_images_say_what_is_wrong():
    with pytest.raises(ValueError, match="two uint8 images of one shape"):
        count_pairs(np.zeros((2, 3), np.uint8), np.zeros((3, 2), np.uint8))
    with pytest.raises(ValueError, match=r"two uint8 images of one shape .*, got int64"):
        count_pairs(np.zeros((2, 3), np.int64), np.zeros((2, 3), np.uint8))
    with pytest.raises(ValueError, match=r"channel 0 or 1.*channel 2"):
        count_pairs(np.zeros((2, 3), np.uint8), np.zeros((2, 3, 2), np.uint8), 2)
    with pytest.raises(ValueError, match="channel 0 or 1"):
        count_pairs(np.zeros((2, 3), np.uint8), np.zeros((2, 3, 3), np.uint8))
