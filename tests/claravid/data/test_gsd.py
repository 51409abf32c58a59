"""Ground sampling distance of ClaraVid frames."""

import numpy as np
import pytest

from claravid.data.gsd import centre_depth, frame_gsd, median_gsd
from claravid.io import modalities

FOCAL = 2627.3023516478706  # fx at 4032 px wide (the dataset's intrinsics)


def test_centre_depth_is_the_mean_of_the_pixels_touching_the_centre():
    depth = np.arange(20, dtype=np.float32).reshape(4, 5)  # even rows, odd columns
    assert centre_depth(depth) == (7 + 12) / 2
    assert centre_depth(np.arange(12, dtype=np.float32).reshape(3, 4)) == (5 + 6) / 2
    assert centre_depth(np.arange(16, dtype=np.float32).reshape(4, 4)) == (5 + 6 + 9 + 10) / 4


def test_frame_gsd_scales_the_focal_length_with_the_frame():
    # 100 m straight down at native size: 100 / 2627.30 m per pixel; at 1008 px wide, 4x that.
    assert frame_gsd(np.full((3024, 4032), 100.0, np.float32)) == pytest.approx(100 / FOCAL)
    assert frame_gsd(np.full((756, 1008), 100.0, np.float32)) == pytest.approx(400 / FOCAL)


def test_median_over_frames(tmp_path):
    paths = []
    for i, metres in enumerate([50.0, 80.0, 120.0]):
        paths.append(tmp_path / f"{i}.png")
        modalities.write_depth(paths[-1], np.full((6, 8), metres))
    fx = FOCAL * 8 / 4032
    assert median_gsd(paths) == pytest.approx(80 / fx, rel=1e-5)
    assert median_gsd([]) is None
