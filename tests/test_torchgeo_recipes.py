"""The recipes of docs/data.md "With torchgeo and Lightning", on the tiny ClaraVid tree: what
each way of feeding the segmenter gives. torchgeo's data modules divide images by 255 on the
device (``Normalize(mean=0, std=255)``, ``(x - 0) / 255``): written here as that arithmetic."""

import warnings

import pytest
import torch
from torch.utils.data import DataLoader

from claravid import ClaraVidSegmentation
from claravid.data.transforms import train_transforms
from claravid.models import InputRangeWarning, build_model
from tests.tiny import VIT
from tests.tiny import WIDE_HEAD as HEAD

TINY = {**VIT, "img_size": 28}  # a 2x2 grid at patch 14
CROP = {"crop_height": 28, "crop_width": 42}


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return build_model("dinov2_vits14", num_classes=8, backbone_kwargs=TINY, **HEAD).eval()


def _batch(root, normalize=False):
    dataset = ClaraVidSegmentation(
        root, split="all", palette="uavid", transforms=train_transforms(CROP, normalize=normalize)
    )
    torch.manual_seed(0)
    return next(iter(DataLoader(dataset, batch_size=4, shuffle=True)))


def _logits(model, x):
    with torch.no_grad():
        return model(x)


def test_uint8_samples_go_to_the_segmenter_as_they_are(claravid_root, model):
    batch = _batch(claravid_root)
    assert batch["image"].dtype == torch.uint8
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the recipe: torchgeo's aug replaced by the identity
        _logits(model, batch["image"])


def test_torchgeo_s_division_by_255_alone_is_taken_for_raw_pixels(claravid_root):
    torch.manual_seed(0)
    fresh = build_model("dinov2_vits14", num_classes=8, backbone_kwargs=TINY, **HEAD).eval()
    unit = _batch(claravid_root)["image"] / 255  # torchgeo's default aug: floats in [0, 1]
    with pytest.warns(InputRangeWarning, match=r"raw pixels in \[0, 1\]"):
        _logits(fresh, unit)


def test_normalize_true_then_torchgeo_s_division_warns_normalised_twice(claravid_root):
    torch.manual_seed(0)
    fresh = build_model("dinov2_vits14", num_classes=8, backbone_kwargs=TINY, **HEAD).eval()
    twice = _batch(claravid_root, normalize=True)["image"] / 255
    with pytest.warns(InputRangeWarning, match=r"normalised twice.*normalize=True"):
        _logits(fresh, twice)


def test_unit_floats_normalised_with_the_model_s_statistics_equal_uint8(claravid_root, model):
    # The kornia recipe: divide by 255 (augment in [0, 1]), then (x - mean) / std with the
    # model's own statistics; no augmentation here, so the logits are uint8's.
    pixels = _batch(claravid_root)["image"]
    mean = torch.tensor(model.mean).view(1, 3, 1, 1)
    std = torch.tensor(model.std).view(1, 3, 1, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = _logits(model, (pixels / 255 - mean) / std)
    torch.testing.assert_close(got, _logits(model, pixels), atol=1e-5, rtol=0)
