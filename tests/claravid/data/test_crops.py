"""Training crops read by window: the crop's pixels are a full decode's, the sample says where
it was cut from, and the window path gives the same samples as cutting a full frame."""

import numpy as np
import pytest
import torch

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.transforms import AugmentConfig, train_transforms
from claravid.io import jpeg_region, modalities
from claravid.synth import synthesize
from claravid.train.data import CropDataset

#: Every augmentation off: a crop is the stored pixels.
PLAIN = {"hflip_p": 0.0, "color_jitter_p": 0.0, "lighting_p": 0.0, "rotate_p": 0.0,
         "distortion_p": 0.0}  # fmt: skip


@pytest.fixture(scope="module")
def odd_root(tmp_path_factory):
    """Frames of 203×141 (no multiple of a JPEG block), one mission."""
    root = tmp_path_factory.mktemp("odd") / "root"
    synthesize(root, seed=3, frames_per_viewpoint=2, size=(203, 141), missions=["urban_1"])
    return root


def _pixels(sample):
    """The crop's pixels, H×W×3: the transforms hand them out as stored (uint8)."""
    assert sample["image"].dtype == torch.uint8
    return sample["image"].permute(1, 2, 0).numpy()


@pytest.mark.parametrize("cache", [False, True])
def test_a_crop_is_the_full_decode_over_its_window(odd_root, tmp_path, cache):
    transforms = train_transforms(AugmentConfig(crop_height=70, crop_width=90, **PLAIN))
    ds = ClaraVidSegmentation(odd_root, split="all", palette="uavid", transforms=transforms,
                              label_cache=tmp_path if cache else False)  # fmt: skip
    whole = ClaraVidSegmentation(odd_root, split="all", palette="uavid")
    windows = set()
    for index in range(len(ds)):
        for seed in range(4):
            transforms.pipeline.set_random_seed(seed)
            sample = ds[index]
            x, y, w, h = sample["crop"]
            assert (w, h) == (90, 70) and 0 <= x <= 203 - 90 and 0 <= y <= 141 - 70
            rgb = modalities.read_rgb(sample["path"])
            np.testing.assert_array_equal(_pixels(sample), rgb[y : y + h, x : x + w])
            ids = whole.read_mask(index)
            np.testing.assert_array_equal(sample["mask"].numpy(), ids[y : y + h, x : x + w])
            windows.add((x, y))
    assert len(windows) == 4  # each seed its own window (the frames share one size)


def test_a_frame_smaller_than_the_crop_is_padded_with_ignore(claravid_root):
    transforms = train_transforms(AugmentConfig(crop_height=60, crop_width=80, **PLAIN))
    ds = ClaraVidSegmentation(claravid_root, split="all", palette="uavid", transforms=transforms)
    sample = ds[0]
    assert sample["crop"] == (0, 0, 64, 48)  # the whole 64×48 frame, padded to 80×60
    assert tuple(sample["mask"].shape) == (60, 80)
    valid = sample["mask"] != 255
    assert int(valid.sum()) <= 64 * 48 and int((sample["mask"] == 255).sum()) >= 80 * 60 - 64 * 48
    rows, cols = np.nonzero(valid.numpy())
    top, left = rows.min(), cols.min()  # where the frame landed
    rgb = modalities.read_rgb(sample["path"])
    np.testing.assert_array_equal(_pixels(sample)[top : top + 48, left : left + 64], rgb)
    assert _pixels(sample).sum() == rgb.astype(np.int64).sum()  # the padding is black


class _FullFrames(torch.utils.data.Dataset):
    """The same frames through the plain dataset interface alone (no read_window)."""

    def __init__(self, base):
        self.base = base

    def __len__(self):
        return len(self.base)

    def __getitem__(self, index):
        return self.base[index]


@pytest.mark.parametrize(("k", "crop"), [(1, (64, 96)), (3, (64, 96)), (2, (160, 96))])
def test_window_reads_give_the_crops_of_full_frames(odd_root, k, crop):
    # With every augmentation on: the window drawn before decoding and the crop cut from a
    # full frame are the same draw of the same stream, so the training batches are identical;
    # also when the frame (141 rows) is shorter than the crop (160) and is padded at random.
    augment = AugmentConfig(crop_height=crop[0], crop_width=crop[1])
    base = ClaraVidSegmentation(odd_root, split="all", palette="uavid")
    by_window = CropDataset(base, augment, k, by_window=True)
    by_frame = CropDataset(base, augment, k, by_window=False)
    assert CropDataset(_FullFrames(base), augment, k).by_window is False  # cannot read windows
    for item in [(0, 11), (1, 12345), (3, 2**31)]:
        a, b = by_window[item], by_frame[item]
        torch.testing.assert_close(a["image"], b["image"], rtol=0, atol=0)
        torch.testing.assert_close(a["mask"], b["mask"], rtol=0, atol=0)


def test_prepared_labels_and_rgb_windows_decode_no_whole_frame(odd_root, tmp_path, monkeypatch):
    if jpeg_region.decoder() != jpeg_region.REGION_DECODE:
        pytest.skip("the C window decoder is not built here (CI requires it: test_jpeg_region)")
    transforms = train_transforms(AugmentConfig(crop_height=64, crop_width=64))
    ds = ClaraVidSegmentation(odd_root, split="all", palette="claravid", label_cache=tmp_path,
                              transforms=transforms)  # fmt: skip
    summary = ds.prepare_label_cache()
    assert summary.built == len(ds) and ds.prepare_label_cache().built == 0

    def refuse(*args, **kwargs):
        raise AssertionError("a whole frame was decoded")

    monkeypatch.setattr(modalities, "read_semantic", refuse)  # the panoptic PNG
    monkeypatch.setattr(jpeg_region, "read_rgb", refuse)  # the full-decode fallback
    for index in range(len(ds)):
        assert tuple(ds[index]["mask"].shape) == (64, 64)
