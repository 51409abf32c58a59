"""ClaraVidSegmentation: samples, palettes on real files, splits, cache, errors, DataLoader."""

import json

import cv2
import numpy as np
import pytest
import torch
from matplotlib.figure import Figure
from torch.utils.data import DataLoader

from claravid import ClaraVidSegmentation, CorruptFileError
from claravid.data.transforms import train_transforms
from claravid.io import modalities as m
from claravid.io.labels import UnknownClassWarning

CLARAVID_TRAIN_ID = {0: 0, 1: 1, 2: 2, 3: 3, 4: 4, 5: 5, 6: 6, 7: 7, 8: 8, 9: 9, 10: 10,
                     13: 11, 14: 12, 15: 13, 16: 14, 17: 15, 18: 16, 19: 17, 22: 18}  # fmt: skip


def test_sample_without_transforms_is_exact(claravid_root):
    ds = ClaraVidSegmentation(claravid_root, split="all")
    sample = ds[4]
    frame = ds.frames[4]
    assert sample["image"].dtype == torch.uint8 and sample["image"].shape == (3, 48, 64)
    assert sample["mask"].dtype == torch.int64 and sample["mask"].shape == (48, 64)
    assert sample["path"] == str(frame.paths["rgb"]) and sample["mission"] == frame.mission
    assert sample["viewpoint"] == frame.viewpoint
    rgb = m.read_rgb(frame.paths["rgb"])
    np.testing.assert_array_equal(sample["image"].permute(1, 2, 0).numpy(), rgb)
    semantic = m.read_pan_seg(frame.paths["pan_seg"])[..., 1]
    expected = np.vectorize(lambda c: CLARAVID_TRAIN_ID.get(c, 255))(semantic)
    np.testing.assert_array_equal(sample["mask"].numpy(), expected)


def test_uavid_moving_and_static_cars_on_generated_frames(claravid_root):
    ds = ClaraVidSegmentation(claravid_root, split="all", palette="uavid", missions=["urban_1"])
    moving = static = 0
    for i in range(len(ds)):
        frame = ds.frames[i]
        semantic = m.read_pan_seg(frame.paths["pan_seg"])[..., 1]
        dynamic = m.read_dynamic_mask(frame.paths["dynamic_mask"]) == 0
        mask = ds[i]["mask"].numpy()
        vehicles = semantic == 9
        assert (mask[vehicles & dynamic] == 7).all() and (mask[vehicles & ~dynamic] == 3).all()
        assert (mask[semantic == 8] == 4).all() and (mask[semantic == 255] == 255).all()
        moving += int((vehicles & dynamic).sum())
        static += int((vehicles & ~dynamic).sum())
    assert moving > 0 and static > 0  # the generator marks some vehicles dynamic


def test_unknown_ids_ignored_and_counted(writable_root):
    ds = ClaraVidSegmentation(writable_root, split="all", missions=["urban_1"])
    frame = ds.frames[0]
    pan = m.read_pan_seg(frame.paths["pan_seg"])
    semantic = pan[..., 1].astype(np.uint8)
    semantic[:2, :5] = 11  # an unused id
    semantic[2, 0] = 200
    m.write_pan_seg(frame.paths["pan_seg"], semantic, pan[..., 0])
    with pytest.warns(UnknownClassWarning, match=r"11 pixel\(s\) of .*000000\.png"):
        mask = ds[0]["mask"]
    assert (mask[:2, :5] == 255).all() and mask[2, 0] == 255


def test_splits_disjoint_and_cover(claravid_root):
    config = {"block_size": 20.0}
    parts = [
        ClaraVidSegmentation(claravid_root, split=s, split_config=config)
        for s in ("train", "val", "test")
    ]
    keys = [{f.key for f in p.frames} for p in parts]
    assert not (keys[0] & keys[1] or keys[0] & keys[2] or keys[1] & keys[2])
    assert sum(map(len, keys)) == len(ClaraVidSegmentation(claravid_root, split="all"))
    held = ClaraVidSegmentation(
        claravid_root, split="test", split_config={"test_missions": ["urban_1"]}
    )
    assert {f.mission for f in held.frames} == {"urban_1"}


def test_label_cache_gives_identical_masks_and_follows_edits(writable_root, tmp_path):
    plain = ClaraVidSegmentation(writable_root, split="all", palette="uavid")
    cached = ClaraVidSegmentation(
        writable_root, split="all", palette="uavid", label_cache=tmp_path / "c"
    )
    for i in (0, 7):
        np.testing.assert_array_equal(cached.read_mask(i), plain.read_mask(i))
        np.testing.assert_array_equal(cached.read_mask(i), plain.read_mask(i))  # from the cache
    assert len(list((tmp_path / "c").rglob("*.tif"))) == 2
    frame = plain.frames[0]
    pan = m.read_pan_seg(frame.paths["pan_seg"])
    m.write_pan_seg(frame.paths["pan_seg"], np.full(pan.shape[:2], 6, np.uint8), pan[..., 0])
    assert (cached.read_mask(0) == 2).all()  # Road, not the stale cached labels


def test_class_frequencies_exact_and_cached(claravid_root):
    ds = ClaraVidSegmentation(claravid_root, split="all", palette="uavid", missions=["rural_1"])
    brute = np.zeros(8, np.int64)
    for i in range(len(ds)):
        ids = ds[i]["mask"].numpy()
        brute += np.bincount(ids[ids != 255], minlength=8)
    counts = ds.class_frequencies(progress=False)
    np.testing.assert_array_equal(counts, brute)
    assert counts.dtype == np.int64
    ds.read_mask = None  # a second call must not read any label
    np.testing.assert_array_equal(ds.class_frequencies(progress=False), brute)


def test_size_mismatch_and_corrupt_files_name_the_files(writable_root):
    ds = ClaraVidSegmentation(writable_root, split="all", missions=["rural_1"])
    frame = ds.frames[0]
    m.write_pan_seg(frame.paths["pan_seg"], np.zeros((10, 10), np.uint8), np.zeros((10, 10)))
    with pytest.raises(
        ValueError, match=r"size mismatch: .*000000\.jpg is 64×48 but .*000000\.png is 10×10"
    ):
        ds[0]
    rgb = ds.frames[1].paths["rgb"]
    rgb.write_bytes(rgb.read_bytes()[:200])
    with pytest.raises(CorruptFileError, match=r"000001\.jpg.*truncated"):
        ds[1]


def test_dataloader_with_two_workers_and_augmentations(claravid_root):
    # Each sample's values, computed independently: the stored pixels of its window (OpenCV's
    # full decode) normalised by hand, flipped or not (p = 0.5), and the mask of the full frame
    # over the same window, flipped alike.
    mean, std = np.array([0.3, 0.5, 0.7]), np.array([0.2, 0.25, 0.5])
    off = dict.fromkeys(["color_jitter_p", "lighting_p", "rotate_p", "distortion_p"], 0.0)
    cfg = {"crop_height": 32, "crop_width": 40, "hflip_p": 0.5, "mean": mean.tolist(),
           "std": std.tolist(), **off}  # fmt: skip
    ds = ClaraVidSegmentation(
        claravid_root,
        split="all",
        palette="uavid",
        transforms=train_transforms(cfg, normalize=True),
    )
    whole = ClaraVidSegmentation(claravid_root, split="all", palette="uavid")
    masks = {str(f.paths["rgb"]): whole.read_mask(i) for i, f in enumerate(whole.frames)}
    loader = DataLoader(ds, batch_size=4, num_workers=2, shuffle=True)
    seen, flips = [], {True: 0, False: 0}
    for batch in loader:
        assert batch["image"].dtype == torch.float32 and batch["mask"].dtype == torch.int64
        for i, path in enumerate(batch["path"]):
            x, y, w, h = (int(v[i]) for v in batch["crop"])
            assert (w, h) == (40, 32)
            rgb = cv2.imread(path, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)[..., ::-1]
            image = (rgb[y : y + h, x : x + w] / 255.0 - mean) / std
            mask = masks[path][y : y + h, x : x + w]
            got = batch["image"][i].permute(1, 2, 0).numpy()
            flipped = not np.allclose(got, image, atol=1e-5)
            if flipped:
                image, mask = image[:, ::-1], mask[:, ::-1]
            np.testing.assert_allclose(got, image, atol=1e-5)
            np.testing.assert_array_equal(batch["mask"][i].numpy(), mask)
            flips[flipped] += 1
            seen.append(path)
    assert sorted(seen) == sorted(masks)  # every frame once
    assert flips[True] > 0 and flips[False] > 0


def test_plot_with_prediction(claravid_root):
    ds = ClaraVidSegmentation(claravid_root, split="all")
    sample = ds[0]
    sample["prediction"] = sample["mask"].clone()
    fig = ds.plot(sample, suptitle="frame 0")
    assert isinstance(fig, Figure) and len(fig.axes) == 3
    present = {ds.classes[i] if i != 255 else "ignore" for i in sample["mask"].unique().tolist()}
    assert {t.get_text() for t in fig.legends[0].get_texts()} == present


def test_unknown_id_count_is_exact_on_dynamic_pixels_and_through_the_cache(writable_root, tmp_path):
    ds = ClaraVidSegmentation(
        writable_root, split="all", palette="uavid", missions=["urban_1"], label_cache=tmp_path
    )
    frame = ds.frames[0]
    pan = m.read_pan_seg(frame.paths["pan_seg"])
    semantic = pan[..., 1].astype(np.uint8)
    semantic[0, :4] = 12  # unused id on pixels marked dynamic below
    semantic[1, :3] = 140  # 140 - 128 = 12: must not pass for a dynamic code
    semantic[2, 0] = 254  # the code of unknown ids itself
    m.write_pan_seg(frame.paths["pan_seg"], semantic, pan[..., 0])
    dynamic = m.read_dynamic_mask(frame.paths["dynamic_mask"])
    dynamic[:2, :4] = 0
    m.write_dynamic_mask(frame.paths["dynamic_mask"], dynamic)
    for _ in range(2):  # decoded, then read back from the label cache
        with pytest.warns(UnknownClassWarning, match=r"^8 pixel\(s\) of .*000000\.png"):
            mask = ds[0]["mask"]
        assert (mask[0, :4] == 255).all() and (mask[1, :3] == 255).all() and mask[2, 0] == 255


def test_label_file_of_the_wrong_kind_names_the_file(writable_root):
    ds = ClaraVidSegmentation(writable_root, split="all", missions=["rural_1"])
    pan_seg = ds.frames[2].paths["pan_seg"]
    semantic = m.read_pan_seg(pan_seg)[..., 1].astype(np.uint16)
    cv2.imwrite(str(pan_seg), np.dstack([semantic] * 3) * 257)  # 16-bit: once read as Building
    with pytest.raises(CorruptFileError, match=r"000002\.png: expected an 8-bit RGB.*16-bit"):
        ds[2]


def test_nan_extrinsics_and_bad_split_config_name_the_problem(writable_root):
    pose = writable_root / "001_rural_1" / "extrinsics" / "55deg_mid_h" / "000001.json"
    rows = json.loads(pose.read_text())
    rows[0][3] = float("nan")
    pose.write_text(json.dumps(rows))  # json writes the literal NaN, as some tools do
    with pytest.raises(CorruptFileError, match=r"000001\.json: the 4×4 pose holds NaN"):
        ClaraVidSegmentation(writable_root, split="train", missions=["rural_1"])
    with pytest.raises(ValueError, match=r"unknown split_config key\(s\) \['test_mission'\]"):
        ClaraVidSegmentation(writable_root, split="all", split_config={"test_mission": "urban_1"})


def test_partial_download_with_a_missing_rgb(writable_root):
    (writable_root / "003_urban_1" / "left_rgb" / "90deg_high_h" / "000000.jpg").unlink()
    with pytest.raises(FileNotFoundError, match=r"90deg_high_h/000000\.jpg"):
        ClaraVidSegmentation(writable_root, split="all")
    with pytest.warns(UserWarning, match=r"left out 1 incomplete frame"):
        ds = ClaraVidSegmentation(writable_root, split="all", skip_incomplete=True)
    assert len(ds) == 2 * 6 * 3 - 1
