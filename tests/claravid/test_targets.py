"""UAVid and image folders: colour labels to train ids, test split without labels, errors."""

import numpy as np
import pytest
import torch

from claravid import DatasetNotFoundError, ImageFolder, UAVidSegmentation
from claravid import modalities as m
from claravid.palettes import load_palette
from claravid.targets import UnknownColorWarning

COLORS = load_palette("uavid").colors


@pytest.fixture
def uavid_root(tmp_path):
    """uavid_{train,val,test}/seqN with 2 frames each; test without labels."""
    rng = np.random.default_rng(0)
    for split in ("train", "val", "test"):
        for seq in (1, 2):
            for frame in range(2):
                base = tmp_path / f"uavid_{split}" / f"seq{seq}"
                ids = rng.integers(0, 8, (24, 32))
                m._write_image(
                    base / "Images" / f"{frame:06d}.png",
                    rng.integers(0, 256, (24, 32, 3), dtype=np.uint8),
                )
                if split != "test":
                    m.write_seg_color(base / "Labels" / f"{frame:06d}.png", COLORS[ids])
                    np.save(base / f"ids{frame}.npy", ids)
    return tmp_path


def test_labels_decode_to_uavid_train_ids(uavid_root):
    ds = UAVidSegmentation(uavid_root, split="train")
    assert len(ds) == 4 and ds.classes[7] == "Moving car"
    sample = ds[3]
    assert sample["image"].shape == (3, 24, 32) and sample["mask"].dtype == torch.int64
    assert sample["sequence"] == "seq2"
    expected = np.load(uavid_root / "uavid_train" / "seq2" / "ids1.npy")
    np.testing.assert_array_equal(sample["mask"].numpy(), expected)


def test_test_split_has_no_mask_and_unknown_colours_are_ignored(uavid_root):
    sample = UAVidSegmentation(uavid_root, split="test")[0]
    assert "mask" not in sample and sample["image"].dtype == torch.uint8
    label = uavid_root / "uavid_val" / "seq1" / "Labels" / "000000.png"
    colors = m.read_seg_color(label)
    colors[0, :3] = (1, 2, 3)
    m.write_seg_color(label, colors)
    with pytest.warns(UnknownColorWarning, match=r"3 pixel\(s\) of .*000000\.png"):
        mask = UAVidSegmentation(uavid_root, split="val")[0]["mask"]
    assert (mask[0, :3] == 255).all()


def test_uavid_errors(uavid_root, tmp_path):
    with pytest.raises(ValueError, match="unknown UAVid split 'training'"):
        UAVidSegmentation(uavid_root, split="training")
    with pytest.raises(DatasetNotFoundError, match=r"UAVid val split not found.*uavid_val"):
        UAVidSegmentation(tmp_path / "empty", split="val")
    (uavid_root / "uavid_train" / "seq1" / "Labels" / "000001.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"1 UAVid label\(s\) missing.*000001\.png"):
        UAVidSegmentation(uavid_root, split="train")
    m.write_seg_color(
        uavid_root / "uavid_val" / "seq1" / "Labels" / "000000.png", COLORS[np.zeros((5, 5), int)]
    )
    with pytest.raises(ValueError, match=r"size mismatch: .*000000\.png is 32×24 but"):
        UAVidSegmentation(uavid_root, split="val")[0]


def test_image_folder(uavid_root, tmp_path):
    ds = ImageFolder(uavid_root / "uavid_test")
    assert len(ds) == 4 and ds[0]["image"].shape == (3, 24, 32) and ds[0]["path"].endswith(".png")
    assert len(ImageFolder(uavid_root, pattern="uavid_val/seq1/Images/*.png")) == 2
    (tmp_path / "nothing").mkdir()
    with pytest.raises(DatasetNotFoundError, match=r"images matching .* not found"):
        ImageFolder(tmp_path / "nothing")
