"""ClaravidDataset: the official SDK's frame order, defaults, keys, dtypes and values."""

import numpy as np
import pytest

from claravid import ClaravidDataset, DatasetNotFoundError
from claravid import modalities as m
from claravid.layout import ALTITUDES, DIRECTIONS, MISSIONS, MODALITIES

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


def test_missing_root_mission_modality_viewpoint(claravid_root, writable_root, tmp_path):
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
    import shutil

    shutil.rmtree(writable_root / "001_rural_1" / "depth")
    with pytest.raises(DatasetNotFoundError, match=r"modality 'depth' of mission 'rural_1'.*depth"):
        ClaravidDataset(writable_root)
    shutil.rmtree(writable_root / "003_urban_1" / "left_rgb" / "55deg_mid_v")
    with pytest.raises(
        DatasetNotFoundError, match=r"viewpoint '55deg_mid_v'.*contains: 45deg_low_h"
    ):
        ClaravidDataset(writable_root, missions=["urban_1"], altitude=["mid"], fields=["rgb"])


def test_missing_frame_file_error_or_skip(writable_root):
    victim = writable_root / "003_urban_1" / "panoptic_seg" / "45deg_low_h" / "000001.png"
    victim.unlink()
    with pytest.raises(FileNotFoundError, match=r"000001\.png"):
        ClaravidDataset(writable_root, missions=["urban_1"])
    with pytest.warns(UserWarning, match=r"left out 1 incomplete"):
        ds = ClaravidDataset(writable_root, missions=["urban_1"], skip_incomplete=True)
    assert len(ds) == 6 * 3 - 1


def test_index_out_of_range(claravid_root):
    ds = ClaravidDataset(claravid_root, fields=["extrinsics"])
    assert ds[-1]["frame_idx"] == len(ds) - 1
    with pytest.raises(IndexError, match="out of range"):
        ds[len(ds)]
