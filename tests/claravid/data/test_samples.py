"""claravid.data.samples.normalise: uint8 images normalised; float images only when normalised.

Expected ranges are computed by hand from the ImageNet statistics: channel c of a normalised
image lies in [(0 - mean_c) / std_c, (1 - mean_c) / std_c], i.e. [-2.1179, 2.2489] (R),
[-2.0357, 2.4286] (G), [-1.8044, 2.64] (B).
"""

import albumentations as A
import numpy as np
import pytest
import torch

from claravid.data.samples import normalise
from claravid.data.transforms import IMAGENET_MEAN, IMAGENET_STD

MEAN, STD = IMAGENET_MEAN, IMAGENET_STD


def test_a_float_image_of_0_to_255_pixels_is_refused():
    # What a dataset without a normalising transform would hand over as float: silently wrong
    # before (returned as "normalised already").
    rgb = torch.arange(2 * 3 * 5 * 7, dtype=torch.float32).reshape(2, 3, 5, 7) % 256
    with pytest.raises(
        ValueError,
        match=r"channel 0 values in \[0, 139\], outside "
        r"\[-2\.118, 2\.249\].*pass uint8 images",
    ):
        normalise(rgb, MEAN, STD)
    with pytest.raises(ValueError, match="not normalised"):
        normalise(rgb[0], MEAN, STD)  # one image [3,H,W] too


def test_an_image_normalised_by_albumentations_passes_unchanged():
    rgb = np.random.default_rng(0).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    rgb[0, 0], rgb[0, 1] = 0, 255  # the extremes of every channel
    normalised = A.Normalize(mean=MEAN, std=STD, max_pixel_value=255.0)(image=rgb)["image"]
    image = torch.from_numpy(normalised.transpose(2, 0, 1).copy())
    assert normalise(image, MEAN, STD) is image
    assert normalise(image[None].expand(3, 3, 5, 7), MEAN, STD).shape == (3, 3, 5, 7)


def test_the_range_is_per_channel_and_its_bounds_are_inclusive():
    bounds = [((0 - m) / s, (1 - m) / s) for m, s in zip(MEAN, STD, strict=True)]
    image = torch.zeros(3, 2, 4)
    for c, (lo, hi) in enumerate(bounds):
        image[c, 0, 0], image[c, 1, 3] = lo, hi
    assert normalise(image, MEAN, STD) is image  # exactly the extremes: fine
    # 2.5 is inside blue's range (up to 2.64) but beyond red's (2.2489) and green's (2.4286):
    # a check over the wrong axis, or over all channels at once, gets one of these wrong.
    blue = image.clone()
    blue[2, 0, 1] = 2.5
    assert normalise(blue, MEAN, STD) is blue
    for c in (0, 1):
        red = image.clone()
        red[c, 0, 1] = 2.5
        with pytest.raises(ValueError, match=rf"channel {c} values"):
            normalise(red, MEAN, STD)
    below = image.clone()
    below[2, 1, 1] = bounds[2][0] - 0.01  # -1.8144: below blue's -1.8044
    with pytest.raises(ValueError, match=r"channel 2 values in \[-1\.814"):
        normalise(below, MEAN, STD)
    batch = image[None].repeat(4, 1, 1, 1)
    batch[3, 1, 0, 0] = 2.5  # the last image of a batch, channel 1
    with pytest.raises(ValueError, match="channel 1 values"):
        normalise(batch, MEAN, STD)


def test_nan_is_refused_and_uint8_is_normalised_by_hand():
    image = torch.zeros(3, 2, 2)
    image[1, 1, 1] = float("nan")
    with pytest.raises(ValueError, match="channel 1"):
        normalise(image, MEAN, STD)
    pixels = torch.tensor([0, 255, 51], dtype=torch.uint8).view(3, 1, 1)
    out = normalise(pixels, (0.0, 0.5, 0.1), (1.0, 0.25, 0.5))
    # 0/255 = 0; (1 - 0.5) / 0.25 = 2; (0.2 - 0.1) / 0.5 = 0.2
    torch.testing.assert_close(out.flatten(), torch.tensor([0.0, 2.0, 0.2]), rtol=0, atol=1e-6)
