"""ClaravidDataset: the official SDK's frame order, defaults, keys, dtypes and values."""

import shutil

import numpy as np
import pytest

from claravid import ClaravidDataset, DatasetNotFoundError
from claravid.io import modalities as m
from claravid.io.layout import ALTITUDES, DIRECTIONS, MISSIONS, MODALITIES

FILE_FIELDS = [k for k, mod in MODALITIES.items() if mod.folder]


def sdk_path_list(root, missions, altitudes, directions, fields):
    """The SDK's listing: mission, altitude, direction, sorted anchor file names."""
    out = []
    for mission in missions:
        for alt in altitudes:
            for drc in directions:
                anchor = MODALITIES[fields[0]]
                folder = root / MISSIONS[mission] / anchor.folder / f"{ALTITUDES[alt]}_{drc}"
                for file in sorted(folder.glob(f"*.{anchor.ext}")):
                    out.append(
                        {
                            f: root / MISSIONS[mission] / MODALITIES[f].folder
                            / f"{ALTITUDES[alt]}_{drc}" / f"{file.stem}.{MODALITIES[f].ext}"
                            for f in fields
                            if MODALITIES[f].folder
                        }
                    )  # fmt: skip
    return out


def test_defaults_order_and_item(claravid_root):
    ds = ClaravidDataset(claravid_root)
    assert ds.fields == list(MODALITIES) and ds.altitude == ["low", "mid", "high"]
    assert ds.direction == ["h", "v"]
    assert len(ds) == 2 * 6 * 3
    expected = sdk_path_list(
        claravid_root, ["rural_1", "urban_1"], ALTITUDES, DIRECTIONS, FILE_FIELDS
    )
    assert ds.path_list == expected
    item = ds[5]
    assert set(item) == set(MODALITIES) | {"frame_idx"} and item["frame_idx"] == 5
    shapes = {k: (v.dtype, v.shape) for k, v in item.items() if k != "frame_idx"}
    assert shapes == {
        "rgb": (np.uint8, (48, 64, 3)),
        "depth": (np.float32, (48, 64)),
        "seg_color": (np.uint8, (48, 64, 3)),
        "pan_seg": (np.int32, (48, 64, 2)),
        "dynamic_mask": (np.uint8, (48, 64)),
        "extrinsics": (np.float32, (4, 4)),
        "intrinsics": (np.float32, (3, 3)),
    }
    paths = ds.path_list[5]
    np.testing.assert_array_equal(item["depth"], m.read_depth(paths["depth"]))
    np.testing.assert_array_equal(item["pan_seg"], m.read_pan_seg(paths["pan_seg"]))
    np.testing.assert_array_equal(item["extrinsics"], m.read_extrinsics(paths["extrinsics"]))
    np.testing.assert_array_equal(item["intrinsics"], ClaravidDataset.K)
    np.testing.assert_array_equal(ds.read_dynamic_mask(5), item["dynamic_mask"])


def test_selection_and_anchor(claravid_root):
    ds = ClaravidDataset(
        claravid_root, missions=["urban_1"], altitude=["high"], direction=["v"],
        fields=["pan_seg", "rgb"],
    )  # fmt: skip
    assert len(ds) == 3
    assert ds.path_list == sdk_path_list(
        claravid_root, ["urban_1"], ["high"], ["v"], ["pan_seg", "rgb"]
    )
    assert list(ds[0]) == ["pan_seg", "rgb", "frame_idx"]
    assert [f.viewpoint for f in ds.frames] == ["90deg_high_v"] * 3
    # Mission order follows the request, as in the SDK.
    both = ClaravidDataset(claravid_root, missions=["urban_1", "rural_1"], fields=["rgb"])
    assert [f.mission for f in both.frames[:1] + both.frames[-1:]] == ["urban_1", "rural_1"]


def test_paths_func_is_honoured(claravid_root):
    def only_first(root, missions, fields, viewpoint_altitude, viewpoint_direction):
        return sdk_path_list(root, missions, viewpoint_altitude, viewpoint_direction, fields)[:1]

    ds = ClaravidDataset(claravid_root, missions=["rural_1"], fields=["rgb"], paths_func=only_first)
    assert len(ds) == 1


def test_missing_root_mission_modality(claravid_root, writable_root, tmp_path):
    with pytest.raises(DatasetNotFoundError, match=r"ClaraVid root not found: searched .*nowhere"):
        ClaravidDataset(tmp_path / "nowhere")
    with pytest.raises(
        DatasetNotFoundError, match=r"mission 'urban_2'.*contains: 001_rural_1, 003_urban_1"
    ):
        ClaravidDataset(claravid_root, missions=["urban_2"])
    with pytest.raises(ValueError, match=r"unknown ClaraVid mission 'urbn_1'"):
        ClaravidDataset(claravid_root, missions=["urbn_1"])
    with pytest.raises(ValueError, match=r"unknown altitude \['top'\]"):
        ClaravidDataset(claravid_root, altitude=["top"])
    with pytest.raises(ValueError, match=r"no direction selected"):
        ClaravidDataset(claravid_root, direction=[])
    shutil.rmtree(writable_root / "001_rural_1" / "depth")
    with pytest.raises(DatasetNotFoundError, match=r"modality 'depth' of mission 'rural_1'.*depth"):
        ClaravidDataset(writable_root)


def remove_viewpoint(root, mission_folder, viewpoint):
    """Delete one viewpoint of a mission in every modality: a partial download."""
    removed = 0
    for modality in MODALITIES.values():
        if modality.folder:
            shutil.rmtree(root / mission_folder / modality.folder / viewpoint)
            removed += 1
    assert removed == 6


def test_partial_download_defaults_mean_all_present(writable_root):
    # urban_1 was downloaded without its vertical mid-altitude pass.
    remove_viewpoint(writable_root, "003_urban_1", "55deg_mid_v")
    ds = ClaravidDataset(writable_root, altitude=["mid"], fields=["rgb", "pan_seg"])
    # rural_1: mid_h + mid_v, urban_1: mid_h only; 3 frames each.
    assert [(f.mission, f.viewpoint) for f in ds.frames] == (
        [("rural_1", "55deg_mid_h")] * 3 + [("rural_1", "55deg_mid_v")] * 3
        + [("urban_1", "55deg_mid_h")] * 3
    )  # fmt: skip
    assert len(ClaravidDataset(writable_root, missions="urban_1", fields="rgb")) == 5 * 3


def test_explicit_key_matching_no_folder_names_what_exists(writable_root):
    for mission in ("001_rural_1", "003_urban_1"):
        for direction in ("h", "v"):
            remove_viewpoint(writable_root, mission, f"90deg_high_{direction}")
    assert len(ClaravidDataset(writable_root, fields=["rgb"])) == 2 * 4 * 3
    with pytest.raises(
        DatasetNotFoundError,
        match=r"altitude 'high' .*rural_1: 45deg_low_h, 45deg_low_v, 55deg_mid_h, 55deg_mid_v",
    ):
        ClaravidDataset(writable_root, altitude=["low", "high"], fields=["rgb"])
    for view in ("45deg_low_v", "55deg_mid_v"):
        remove_viewpoint(writable_root, "003_urban_1", view)
    with pytest.raises(DatasetNotFoundError, match=r"direction 'v' .*urban_1: 45deg_low_h, 55deg"):
        ClaravidDataset(writable_root, missions=["urban_1"], direction="v")


def test_missing_frame_file_error_or_skip(writable_root):
    victim = writable_root / "003_urban_1" / "panoptic_seg" / "45deg_low_h" / "000001.png"
    victim.unlink()
    with pytest.raises(FileNotFoundError, match=r"000001\.png"):
        ClaravidDataset(writable_root, missions=["urban_1"])
    with pytest.warns(UserWarning, match=r"left out 1 incomplete frame\(s\)"):
        ds = ClaravidDataset(writable_root, missions=["urban_1"], skip_incomplete=True)
    assert len(ds) == 6 * 3 - 1


def test_listing_is_symmetric_across_modalities(writable_root):
    # The anchor (first field) misses a file: the frame must not vanish silently.
    rgb = writable_root / "003_urban_1" / "left_rgb" / "45deg_low_h" / "000002.jpg"
    rgb.unlink()
    with pytest.raises(FileNotFoundError, match=r"(?s)1 frame\(s\) miss 1 file.*000002\.jpg"):
        ClaravidDataset(writable_root, missions=["urban_1"], fields=["rgb", "depth"])
    # A whole viewpoint folder absent in one modality: every frame of it is incomplete.
    shutil.rmtree(writable_root / "001_rural_1" / "depth" / "90deg_high_v")
    with pytest.raises(FileNotFoundError, match=r"(?s)3 frame\(s\) miss 3 file.*90deg_high_v"):
        ClaravidDataset(writable_root, missions=["rural_1"], fields=["rgb", "depth"])
    with pytest.warns(UserWarning, match=r"left out 4 incomplete frame\(s\) missing 4 file"):
        ds = ClaravidDataset(writable_root, fields=["rgb", "depth"], skip_incomplete=True)
    assert len(ds) == 2 * 6 * 3 - 4
    assert not {"90deg_high_v"} & {f.viewpoint for f in ds.frames if f.mission == "rural_1"}
    # Fields that do not include the damaged modalities are unaffected.
    assert len(ClaravidDataset(writable_root, fields=["pan_seg"])) == 2 * 6 * 3


def test_index_out_of_range(claravid_root):
    ds = ClaravidDataset(claravid_root, fields=["extrinsics"])
    assert ds[-1]["frame_idx"] == len(ds) - 1
    with pytest.raises(IndexError, match="out of range"):
        ds[len(ds)]
