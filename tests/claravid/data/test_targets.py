"""Real targets: FolderSegmentation (ids, colours, palette PNGs, errors), UAVid."""

import cv2
import numpy as np
import pytest
import torch
from PIL import Image

from claravid import CorruptFileError, DatasetNotFoundError, FolderSegmentation, UAVidSegmentation
from claravid.data.masks import UnknownLabelWarning
from claravid.data.palettes import load_palette
from claravid.data.transforms import train_transforms
from claravid.io import modalities as m

UAVID_COLORS = load_palette("uavid").colors
# UDD6 colours by id, as UDD6 publishes them (docs/data.md; not from the palette file under test).
UDD6_COLORS = [
    (0, 0, 0),
    (102, 102, 156),
    (128, 64, 128),
    (107, 142, 35),
    (0, 0, 142),
    (70, 70, 70),
]


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
                    m.write_seg_color(base / "Labels" / f"{frame:06d}.png", UAVID_COLORS[ids])
                    np.save(base / f"ids{frame}.npy", ids)
    return tmp_path


def test_uavid_labels_decode_to_train_ids_default_split_train(uavid_root):
    ds = UAVidSegmentation(uavid_root)
    assert ds.split == "train" and len(ds) == 4 and ds.classes[7] == "Moving car"
    sample = ds[3]
    assert sample["image"].shape == (3, 24, 32) and sample["mask"].dtype == torch.int64
    assert sample["sequence"] == "seq2" and sample["key"] == "uavid_train/seq2/Images/000001"
    expected = np.load(uavid_root / "uavid_train" / "seq2" / "ids1.npy")
    np.testing.assert_array_equal(sample["mask"].numpy(), expected)


def test_uavid_palette_argument_reads_id_labels(uavid_root, tmp_path):
    # Labels converted to ids of another palette (here: UDD6 ids written as a grey PNG).
    label = uavid_root / "uavid_val" / "seq1" / "Labels" / "000000.png"
    ids = np.arange(24 * 32).reshape(24, 32) % 6
    cv2.imwrite(str(label), ids.astype(np.uint8))
    sample = UAVidSegmentation(uavid_root, split="val", palette="udd6")[0]
    np.testing.assert_array_equal(sample["mask"].numpy(), ids)


def test_uavid_test_split_has_no_mask_and_unknown_colours_are_counted(uavid_root):
    sample = UAVidSegmentation(uavid_root, split="test")[0]
    assert "mask" not in sample and sample["image"].dtype == torch.uint8
    label = uavid_root / "uavid_val" / "seq1" / "Labels" / "000000.png"
    colors = m.read_seg_color(label)
    colors[0, :3] = (1, 2, 3)
    m.write_seg_color(label, colors)
    with pytest.warns(UnknownLabelWarning, match=r"^3 pixel\(s\) of .*000000\.png"):
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
        uavid_root / "uavid_val" / "seq1" / "Labels" / "000000.png",
        UAVID_COLORS[np.zeros((5, 5), int)],
    )
    with pytest.raises(
        ValueError, match=r"size mismatch: .*000000\.png is 32×24 but its mask .*000000\.png is 5×5"
    ):
        UAVidSegmentation(uavid_root, split="val")[0]


def write_image(path, h=12, w=16, seed=0):
    image = np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)
    m._write_image(path, image)
    return m.read_rgb(path)


@pytest.fixture
def folder(tmp_path):
    """images/{a.jpg, b.PNG, sub/c.tif}, masks/{a.png, b.png, sub/c.png}: UDD6 id masks."""
    images, masks = tmp_path / "images", tmp_path / "masks"
    names = {"a": ".jpg", "b": ".PNG", "sub/c": ".tif"}
    for i, (key, ext) in enumerate(names.items()):
        write_image(images / f"{key}{ext}", seed=i)
        ids = (np.arange(12 * 16).reshape(12, 16) + i) % 6
        m._write_image(masks / f"{key}.png", ids.astype(np.uint8))
    return images, masks


def test_folder_with_id_masks_matched_by_relative_path_and_stem(folder):
    images, masks = folder
    ds = FolderSegmentation(images, masks, palette="udd6")
    assert len(ds) == 3 and ds.keys == ["a", "b", "sub/c"]
    assert ds.classes == ("Other", "Facade", "Road", "Vegetation", "Vehicle", "Roof")
    sample = ds[2]
    assert sample["key"] == "sub/c" and sample["path"] == str(images / "sub" / "c.tif")
    assert sample["image"].dtype == torch.uint8 and sample["image"].shape == (3, 12, 16)
    np.testing.assert_array_equal(
        sample["image"].permute(1, 2, 0).numpy(), m.read_rgb(images / "sub" / "c.tif")
    )
    assert sample["mask"].dtype == torch.int64
    expected = (np.arange(12 * 16).reshape(12, 16) + 2) % 6
    np.testing.assert_array_equal(sample["mask"].numpy(), expected)


def test_id_mask_values_outside_the_palette_become_ignore_and_are_counted(folder):
    images, masks = folder
    ids = np.zeros((12, 16), np.uint8)
    ids[0, :4] = 6  # the first id past UDD6's 0..5
    ids[1, :2] = 200
    ids[2, :5] = 255  # ignore: kept, not counted
    cv2.imwrite(str(masks / "a.png"), ids)
    with pytest.warns(UnknownLabelWarning, match=r"^6 pixel\(s\) of .*a\.png .*'udd6'"):
        mask = FolderSegmentation(images, masks, palette="udd6")[0]["mask"].numpy()
    assert (mask[:3][ids[:3] != 0] == 255).all() and (mask[3:] == 0).all()
    assert np.count_nonzero(mask == 255) == 4 + 2 + 5
    # A 16-bit id mask: the same values, the same count.
    cv2.imwrite(str(masks / "a.png"), ids.astype(np.uint16) + np.uint16(1000) * (ids == 200))
    with pytest.warns(UnknownLabelWarning, match=r"^6 pixel\(s\)"):
        mask16 = FolderSegmentation(images, masks, palette="udd6")[0]["mask"].numpy()
    np.testing.assert_array_equal(mask16, mask)


def test_colour_masks_match_palette_colours_exactly(folder):
    images, masks = folder
    ids = (np.arange(12 * 16).reshape(12, 16) * 7) % 6
    rgb = np.asarray(UDD6_COLORS, np.uint8)[ids]
    rgb[5, 5] = (70, 70, 71)  # one off Roof's colour: not a match
    rgb[6, :2] = (255, 255, 255)
    m.write_seg_color(masks / "b.png", rgb)
    with pytest.warns(UnknownLabelWarning, match=r"^3 pixel\(s\) of .*b\.png"):
        mask = FolderSegmentation(images, masks, palette="udd6")[1]["mask"].numpy()
    expected = ids.copy()
    expected[5, 5] = expected[6, 0] = expected[6, 1] = 255
    np.testing.assert_array_equal(mask, expected)


def test_palette_mode_png_indices_are_the_ids(folder):
    # VOC-style SegmentationClass files: palette PNGs whose indices are the class ids.
    images, masks = folder
    ids = (np.arange(12 * 16).reshape(12, 16) // 16) % 12  # row r holds id r (AeroScapes 0..11)
    voc = Image.fromarray(ids.astype(np.uint8), "P")
    voc.putpalette([(i * 37) % 256 for i in range(256 * 3)])  # distinct colours per index
    voc.save(masks / "a.png")
    mask = FolderSegmentation(images, masks, palette="aeroscapes")[0]["mask"].numpy()
    np.testing.assert_array_equal(mask, ids)


def test_palette_png_with_a_repeated_colour_is_refused(folder):
    # Two indices share one colour: the decoded colours cannot tell which index a pixel held.
    images, masks = folder
    voc = Image.fromarray(np.zeros((12, 16), np.uint8), "P")
    voc.putpalette([0, 0, 0] * 256)
    voc.save(masks / "a.png")
    with pytest.raises(CorruptFileError, match=r"a\.png: .*repeats a colour"):
        FolderSegmentation(images, masks, palette="aeroscapes")[0]


def test_images_only_and_with_transforms(folder):
    images, masks = folder
    bare = FolderSegmentation(images)
    sample = bare[1]
    assert "mask" not in sample and sample["key"] == "b" and bare.classes == ()
    augmented = FolderSegmentation(
        images, masks, "udd6", transforms=train_transforms({"crop_height": 8, "crop_width": 8})
    )[0]
    assert augmented["image"].shape == (3, 8, 8) and augmented["image"].dtype == torch.uint8
    assert augmented["mask"].shape == (8, 8) and augmented["mask"].dtype == torch.int64


def test_folder_errors_name_the_files(folder, tmp_path):
    images, masks = folder
    with pytest.raises(ValueError, match=r"pass palette="):
        FolderSegmentation(images, masks)
    (masks / "sub" / "c.png").unlink()
    with pytest.raises(FileNotFoundError, match=r"1 image\(s\) have no mask in .*c\.tif"):
        FolderSegmentation(images, masks, palette="udd6")
    m._write_image(masks / "sub" / "c.png", np.zeros((6, 16), np.uint8))
    with pytest.raises(
        ValueError, match=r"size mismatch: .*c\.tif is 16×12 but its mask .*c\.png is 16×6"
    ):
        FolderSegmentation(images, masks, palette="udd6")[2]
    (masks / "b.png").unlink()
    (masks / "b.jpg").write_bytes(cv2.imencode(".jpg", np.zeros((12, 16), np.uint8))[1].tobytes())
    with pytest.raises(CorruptFileError, match=r"b\.jpg: expected a lossless mask.*JPEG"):
        FolderSegmentation(images, masks, palette="udd6")[1]
    write_image(images / "a.png")
    with pytest.raises(ValueError, match=r"a\.jpg and .*a\.png have the same name"):
        FolderSegmentation(images)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetNotFoundError, match=r"images \(.jpg.*not found: searched .*empty"):
        FolderSegmentation(tmp_path / "empty")
    with pytest.raises(DatasetNotFoundError, match=r"images folder not found: searched .*nowhere"):
        FolderSegmentation(tmp_path / "nowhere")
