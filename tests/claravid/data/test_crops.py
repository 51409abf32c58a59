"""Training crops read by window: the crop's pixels are a full decode's, the sample says where
it was cut from, and the window path gives the same samples as cutting a full frame."""

import builtins
import os
import shutil

import cv2
import numpy as np
import pytest
import torch
from PIL import Image

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
    transforms = train_transforms(AugmentConfig(crop_height=64, crop_width=72, **PLAIN))
    ds = ClaraVidSegmentation(odd_root, split="all", palette="claravid", label_cache=tmp_path,
                              transforms=transforms)  # fmt: skip
    summary = ds.prepare_label_cache()
    assert summary.built == len(ds) and ds.prepare_label_cache().built == 0
    # The expected values, before whole-frame decodes are refused: OpenCV's full decode, and the
    # class ids of the panoptic PNG's red channel read by PIL, as train ids of the claravid
    # palette: the 19 classes of docs/data.md's table in id order; anything else ignore (255).
    class_ids = [*range(11), *range(13, 20), 22]
    expected = []
    for frame in ds.frames:
        rgb = cv2.imread(str(frame.paths["rgb"]), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
        red = np.array(Image.open(frame.paths["pan_seg"]).convert("RGB"))[..., 0]
        ids = np.full(red.shape, 255, np.uint8)
        for train_id, class_id in enumerate(class_ids):
            ids[red == class_id] = train_id
        expected.append((rgb[..., ::-1], ids))

    def refuse(*args, **kwargs):
        raise AssertionError("a whole frame was decoded")

    monkeypatch.setattr(modalities, "read_semantic", refuse)  # the panoptic PNG
    monkeypatch.setattr(jpeg_region.Photo, "full", refuse)  # the full-decode fallback
    windows = set()
    for index in range(len(ds)):
        sample = ds[index]
        x, y, w, h = sample["crop"]
        assert (w, h) == (72, 64)
        rgb, ids = expected[index]
        np.testing.assert_array_equal(_pixels(sample), rgb[y : y + h, x : x + w])
        np.testing.assert_array_equal(sample["mask"].numpy(), ids[y : y + h, x : x + w])
        windows.add((x, y))
    assert len(windows) > 1


def _count_reads(monkeypatch, path):
    """Count the opens of ``path`` (os.open, open, np.fromfile) and every cv2.imdecode call."""
    target = os.path.realpath(path)
    counts = {"opens": 0, "decodes": 0}
    real_os_open, real_open, real_fromfile = os.open, builtins.open, np.fromfile
    real_imdecode = cv2.imdecode

    def mine(file):
        return isinstance(file, (str, os.PathLike)) and os.path.realpath(file) == target

    def os_open(file, *args, **kwargs):
        counts["opens"] += mine(file)
        return real_os_open(file, *args, **kwargs)

    def open_(file, *args, **kwargs):
        counts["opens"] += mine(file)
        return real_open(file, *args, **kwargs)

    def fromfile(file, *args, **kwargs):
        counts["opens"] += mine(file)
        return real_fromfile(file, *args, **kwargs)

    def imdecode(*args, **kwargs):
        counts["decodes"] += 1
        return real_imdecode(*args, **kwargs)

    monkeypatch.setattr(os, "open", os_open)
    monkeypatch.setattr(builtins, "open", open_)
    monkeypatch.setattr(np, "fromfile", fromfile)
    monkeypatch.setattr(cv2, "imdecode", imdecode)
    return counts


@pytest.mark.parametrize("kind", ["jpeg", "png"])
def test_a_crop_reads_its_rgb_file_once_and_decodes_it_at_most_once(
    odd_root, tmp_path, monkeypatch, kind
):
    # Before: the size came from image_size (the JPEG header parsed by two more opens; a PNG
    # decoded whole), then the window read the file again (and decoded a PNG again).
    root = tmp_path / "root"
    shutil.copytree(odd_root, root)
    transforms = train_transforms(AugmentConfig(crop_height=40, crop_width=50, **PLAIN))
    ds = ClaraVidSegmentation(root, split="all", palette="uavid", transforms=transforms,
                              label_cache=tmp_path / "cache")  # fmt: skip
    ds.prepare_label_cache()
    whole = ClaraVidSegmentation(root, split="all", palette="uavid")
    path = ds.frames[2].paths["rgb"]
    rgb = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)[..., ::-1]
    if kind == "png":  # PNG bytes under the .jpg name: lossless, the same pixels
        path.write_bytes(cv2.imencode(".png", rgb[..., ::-1])[1].tobytes())
    ids = whole.read_mask(2)
    native = jpeg_region.decoder() == jpeg_region.REGION_DECODE
    for seed in range(3):
        transforms.pipeline.set_random_seed(seed)
        counts = _count_reads(monkeypatch, path)
        sample = ds[2]
        monkeypatch.undo()
        assert counts["opens"] == 1, counts
        assert counts["decodes"] == (0 if kind == "jpeg" and native else 1), counts
        x, y, w, h = sample["crop"]
        assert (w, h) == (50, 40)
        np.testing.assert_array_equal(_pixels(sample), rgb[y : y + h, x : x + w])
        np.testing.assert_array_equal(sample["mask"].numpy(), ids[y : y + h, x : x + w])
