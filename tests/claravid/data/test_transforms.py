"""Augmentations: crop size, mask values after augmentation, config from YAML, errors."""

import re

import cv2
import numpy as np
import pytest
import torch

from claravid.data.transforms import (
    AugmentConfig,
    augment_config,
    eval_transforms,
    train_transforms,
)

ALLOWED = set(range(8)) | {255}


def sample(h=300, w=400, seed=0):
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    mask = rng.choice(sorted(ALLOWED), (h, w)).astype(np.uint8)
    # A [3,H,W] view, as the dataset hands it over.
    return {"image": torch.from_numpy(image).permute(2, 0, 1), "mask": torch.from_numpy(mask)}


#: A grey level per id (ignore: 0, the image's fill), far apart: the image tells the id.
LEVELS = {0: 30, 1: 55, 2: 80, 3: 105, 4: 130, 5: 155, 6: 180, 7: 205, 255: 0}


def test_geometric_augmentations_move_image_and_mask_together():
    # An image that is its mask: 30×30 blocks of ids, each painted its grey level. Rotation and
    # distortion warp the image (linear) and the mask (nearest) with the same geometry, and fill
    # outside the frame with 0 and the ignore index: wherever the warped image is one flat level
    # over a 5×5 neighbourhood, the mask must hold that level's id. (A mask warped otherwise,
    # filled with another value or interpolated, breaks it.)
    rng = np.random.default_rng(3)
    ids = np.kron(rng.choice(sorted(ALLOWED), (10, 14)), np.ones((30, 30), int)).astype(np.uint8)
    lut = np.zeros(256, np.uint8)
    for class_id, level in LEVELS.items():
        lut[class_id] = level
    image = np.repeat(lut[ids][..., None], 3, axis=2)
    unlevel = {level: class_id for class_id, level in LEVELS.items()}
    transform = train_transforms(
        {"crop_height": 64, "crop_width": 96, "rotate_p": 1.0, "distortion_p": 1.0,
         "color_jitter_p": 0.0, "lighting_p": 0.0}
    )  # fmt: skip
    checked = 0
    for seed in range(10):
        transform.pipeline.set_random_seed(seed)
        pair = {"image": torch.from_numpy(image).permute(2, 0, 1), "mask": torch.from_numpy(ids)}
        out = transform(pair)
        # uint8 by default: the segmenter normalises with its own statistics on its device
        assert out["image"].shape == (3, 64, 96) and out["image"].dtype == torch.uint8
        grey = out["image"].numpy().astype(np.int64)
        assert (grey == grey[0]).all()  # the three channels warp alike
        grey = grey[0]
        flat = np.ones_like(grey, bool)
        for dy in range(-2, 3):
            for dx in range(-2, 3):
                shifted = np.roll(np.roll(grey, dy, 0), dx, 1)
                flat &= shifted == grey
        flat[:2], flat[-2:], flat[:, :2], flat[:, -2:] = False, False, False, False
        flat &= np.isin(grey, list(unlevel))
        assert flat.mean() > 0.3, flat.mean()
        expected = np.vectorize(unlevel.get)(grey[flat])
        np.testing.assert_array_equal(out["mask"].numpy()[flat], expected)
        assert set(out["mask"].unique().tolist()) <= ALLOWED
        checked += int(flat.sum())
    assert checked > 10 * 64 * 96 * 0.3


def test_small_image_is_padded_with_ignore():
    out = train_transforms({"crop_height": 64, "crop_width": 64, "rotate_p": 0})(sample(20, 30))
    mask = out["mask"].numpy()
    assert out["image"].shape == (3, 64, 64)
    assert (mask == 255).sum() >= 64 * 64 - 20 * 30


def test_without_augmentation_the_crop_is_an_exact_window():
    off = dict.fromkeys(["hflip_p", "color_jitter_p", "lighting_p", "rotate_p", "distortion_p"], 0)
    cfg = {"crop_height": 50, "crop_width": 60, **off}
    s = sample(120, 150, seed=5)
    image = s["image"].permute(1, 2, 0).numpy().copy()
    mask = s["mask"].numpy().copy()
    out = train_transforms(cfg)(s)
    assert out["image"].dtype == torch.uint8  # the exact pixels, not a float round trip
    crop = out["image"].permute(1, 2, 0).numpy()
    # Locate the window by its mask and check the pixels match exactly.
    found = False
    for y in range(120 - 50 + 1):
        for x in range(150 - 60 + 1):
            if np.array_equal(mask[y : y + 50, x : x + 60], out["mask"].numpy()):
                np.testing.assert_array_equal(image[y : y + 50, x : x + 60], crop)
                found = True
    assert found


def test_eval_hands_out_the_exact_uint8_frame_and_a_uint8_mask():
    """The evaluation sample is the frame as decoded (uint8, not copied: the segmenter
    normalises it with its own statistics) and a uint8 mask (a 12-Mpixel int64 one is 96 MB)."""
    from claravid.data.samples import finish_sample

    s = sample(40, 50)
    image, mask = s["image"], s["mask"]
    transform = eval_transforms()
    out = finish_sample(transform(s), transform)
    assert out["image"].dtype == torch.uint8 and out["image"].shape == (3, 40, 50)
    assert out["image"].data_ptr() == image.data_ptr()  # the same pixels, untouched
    assert out["mask"].dtype == torch.uint8 and torch.equal(out["mask"], mask)
    # A dataset's explicit mask_dtype wins over the transforms' wish; training transforms
    # leave the dtype to the dataset: int64, for a loss.
    assert finish_sample(sample(40, 50), transform, torch.int64)["mask"].dtype == torch.int64
    crop = train_transforms({"crop_height": 14, "crop_width": 14})
    assert finish_sample(sample(40, 50), crop)["mask"].dtype == torch.int64
    # A numpy [3,H,W] image comes back as a tensor view of the same pixels.
    raw = sample(40, 50)["image"].numpy()
    out = eval_transforms()({"image": raw})
    assert out["image"].dtype == torch.uint8 and np.array_equal(out["image"].numpy(), raw)


def test_normalize_true_uses_the_config_s_statistics_else_imagenet_s():
    """The explicit option for models that do not normalise themselves. Pixel 0, 51, 255 per
    channel: with ImageNet's statistics (0 - 0.485) / 0.229 = -2.117904, (0.2 - 0.456) / 0.224
    = -1.142857, (1 - 0.406) / 0.225 = 2.64; with mean (0, 0.1, 0.5), std (1, 0.5, 0.25):
    0, 0.2, 2."""
    pixels = torch.tensor([0, 51, 255], dtype=torch.uint8).view(3, 1, 1).expand(3, 2, 4)
    for transforms in (eval_transforms, train_transforms):
        extra = {"crop_height": 2, "crop_width": 4} if transforms is train_transforms else {}
        off = dict.fromkeys(
            ["hflip_p", "color_jitter_p", "lighting_p", "rotate_p", "distortion_p"], 0
        )
        out = transforms({**extra, **off}, normalize=True)({"image": pixels.clone()})
        expected = torch.tensor([-2.117904, -1.142857, 2.64]).view(3, 1, 1).expand(3, 2, 4)
        assert out["image"].dtype == torch.float32
        torch.testing.assert_close(out["image"], expected, atol=1e-5, rtol=0)
        cfg = {**extra, **off, "mean": [0.0, 0.1, 0.5], "std": [1.0, 0.5, 0.25]}
        out = transforms(cfg, normalize=True)({"image": pixels.clone()})
        expected = torch.tensor([0.0, 0.2, 2.0]).view(3, 1, 1).expand(3, 2, 4)
        torch.testing.assert_close(out["image"], expected, atol=1e-5, rtol=0)


def test_config_from_yaml_and_unknown_key(tmp_path):
    (tmp_path / "aug.yaml").write_text("crop_height: 320\nhflip_p: 0.0\n")
    cfg = augment_config(tmp_path / "aug.yaml")
    assert cfg.crop_height == 320 and cfg.crop_width == 630 and cfg.hflip_p == 0.0
    with pytest.raises(ValueError, match="crop_hieght"):
        augment_config({"crop_hieght": 3})


def test_mismatched_image_and_mask():
    s = sample(30, 40)
    s["mask"] = s["mask"][:20]
    s["path"] = "frame.jpg"
    with pytest.raises(ValueError, match=r"image 40×30 and mask 40×20 of frame\.jpg differ"):
        eval_transforms()(s)


def test_shipped_augment_yaml_matches_the_defaults():
    from pathlib import Path

    shipped = augment_config(Path(__file__).parents[3] / "configs" / "augment.yaml")
    assert shipped == augment_config()


def test_config_file_with_a_duplicate_key_names_file_and_key(tmp_path):
    (tmp_path / "aug.yaml").write_text("crop_height: 320\nhflip_p: 0.0\ncrop_height: 640\n")
    with pytest.raises(
        ValueError,
        match=r"aug\.yaml: duplicate key .crop_height. \(first on line 1, again on line 3\)",
    ):
        augment_config(tmp_path / "aug.yaml")
    (tmp_path / "bin.yaml").write_bytes(b"\x89PNG\x00\xff")
    with pytest.raises(ValueError, match=r"bin\.yaml"):
        augment_config(tmp_path / "bin.yaml")


BLOCK, STEP = 32, 28  # class blocks of 32×32 px; image value = (id + 1) * 28, 0 = padding


def image_encodes_mask(h=200, w=260, seed=0):
    """A sample whose image is derived from its mask: every channel is (id + 1) * STEP."""
    rng = np.random.default_rng(seed)
    blocks = rng.integers(0, 8, (h // BLOCK + 1, w // BLOCK + 1))
    mask = np.kron(blocks, np.ones((BLOCK, BLOCK), int))[:h, :w].astype(np.uint8)
    mask[:BLOCK, :BLOCK] = 255  # an ignore region: image 0 there, like padding
    value = np.where(mask == 255, 0, (mask.astype(int) + 1) * STEP).astype(np.uint8)
    image = np.repeat(value[..., None], 3, axis=2)
    return {"image": torch.from_numpy(image).permute(2, 0, 1), "mask": torch.from_numpy(mask)}


def decoded_from_image(image):
    """The class ids the augmented image says each pixel has (255 where the image is 0)."""
    value = image[0].numpy() * 255  # mean 0, std 1: back to the pixel value
    ids = np.rint(value / STEP).astype(int) - 1
    return np.where(ids < 0, 255, ids)


def test_image_and_mask_stay_aligned_under_every_geometric_augmentation():
    # Photometric ops off (they would change the code in the image); every geometric op on.
    cfg = {"crop_height": 96, "crop_width": 128, "mean": [0, 0, 0], "std": [1, 1, 1],
           "color_jitter_p": 0, "lighting_p": 0, "rotate_p": 1.0, "distortion_p": 1.0,
           "hflip_p": 1.0}  # fmt: skip
    transform = train_transforms(cfg, normalize=True)  # float images, to decode the codes
    agreements = []
    for seed in range(8):
        transform.pipeline.set_random_seed(seed)
        out = transform(image_encodes_mask(seed=seed))
        mask = out["mask"].numpy().astype(int)
        # Bilinear image vs nearest mask differ only along block edges (about 1 px wide).
        agreements.append(float(np.mean(decoded_from_image(out["image"]) == mask)))
    assert len(agreements) == 8
    assert min(agreements) > 0.9, agreements


def test_the_alignment_check_catches_a_misaligned_mask():
    # The check itself: flipping only the image, or rotating only the image, must fail it.
    s = image_encodes_mask(96, 128, seed=3)
    mask = s["mask"].numpy().astype(int)
    flipped = s["image"].flip(-1).float() / 255
    assert np.mean(decoded_from_image(flipped) == mask) < 0.6
    rotation = cv2.getRotationMatrix2D((64, 48), 10, 1.0)
    rotated = cv2.warpAffine(s["image"].permute(1, 2, 0).numpy(), rotation, (128, 96))
    rotated_image = torch.from_numpy(rotated).permute(2, 0, 1).float() / 255
    assert np.mean(decoded_from_image(rotated_image) == mask) < 0.9
    assert np.mean(decoded_from_image(s["image"].float() / 255) == mask) == 1.0


@pytest.mark.parametrize(
    ("setting", "value", "message"),
    [
        ("crop_height", 0, "crop_height=0: must be between 1 and 65500 pixels"),
        ("crop_width", 10**6, "crop_width=1000000: must be between 1 and 65500 pixels"),
        ("crop_width", 65501, "crop_width=65501: must be between 1 and 65500"),
        ("crop_height", -3, "crop_height=-3: must be between 1 and 65500"),
        ("rotate_p", 1.5, "rotate_p=1.5: a probability, must be between 0 and 1"),
    ],
)
def test_an_unusable_setting_is_refused_naming_it_at_every_entry(tmp_path, setting, value, message):
    # crop_height=0 or 10**6 failed deep inside OpenCV at the first sample.
    for make in (
        lambda: AugmentConfig(**{setting: value}),
        lambda: augment_config({setting: value}),
        lambda: train_transforms({setting: value}),
        lambda: augment_config(_yaml(tmp_path, f"{setting}: {value}\n")),
    ):
        with pytest.raises(ValueError, match=re.escape(message)):
            make()


def test_the_largest_and_smallest_crops_are_accepted():
    assert AugmentConfig(crop_height=1, crop_width=65500).crop_width == 65500
    assert AugmentConfig(crop_height=16384, crop_width=65500).crop_height == 16384
    with pytest.raises(ValueError, match=r"65500×65500 is more than the 1,073,741,824 pixels"):
        AugmentConfig(crop_height=65500, crop_width=65500)
    with pytest.raises(ValueError, match="crop_width=True: must be an integer"):
        AugmentConfig(crop_width=True)


def _yaml(tmp_path, text):
    path = tmp_path / "augment.yaml"
    path.write_text(text)
    return path
