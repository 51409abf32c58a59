"""Spatial-block splits: deterministic, disjoint, near their fractions; split files; hold-outs."""

import numpy as np
import pytest

from claravid.data.index import Frame
from claravid.data.splits import SplitConfig, assign_blocks, read_split_file, select_split


def grid_frames(mission="urban_1", n=20, spacing=40.0):
    """Frames on an n×n camera grid, two viewpoints at each position (as in ClaraVid)."""
    frames, positions = [], []
    for altitude in ("low", "high"):
        for i in range(n):
            for j in range(n):
                stem = f"{i * n + j:06d}"
                frames.append(Frame(mission, altitude, "h", stem, {}))
                positions.append((i * spacing, j * spacing))
    return frames, np.asarray(positions)


def test_blocks_are_disjoint_deterministic_and_near_fractions():
    frames, positions = grid_frames()
    config = SplitConfig(block_size=100.0, fractions=(0.6, 0.2, 0.2), seed=3)
    splits = assign_blocks(frames, positions, config)
    assert splits == assign_blocks(frames, positions, config)
    counts = {s: splits.count(s) for s in ("train", "val", "test")}
    assert sum(counts.values()) == len(frames)
    assert abs(counts["train"] / len(frames) - 0.6) < 0.1
    assert abs(counts["val"] / len(frames) - 0.2) < 0.1
    # No block is shared between splits, so every viewpoint over one block is in one split.
    # The grid (docs/data.md): floor(760 / 100) + 1 = 8 blocks per axis centred on the
    # 0..760 m extent, from -20 m.
    blocks = {}
    for split, pos in zip(splits, positions, strict=True):
        key = tuple(np.floor((pos + 20.0) / 100.0).astype(int))
        assert blocks.setdefault(key, split) == split
    assert len(blocks) == 64
    assert splits != assign_blocks(frames, positions, SplitConfig(block_size=100.0, seed=4))


def test_select_split_partitions_the_frames():
    frames, positions = grid_frames(n=12)
    config = SplitConfig(block_size=80.0)
    parts = {
        s: select_split(frames, s, config, lambda: positions) for s in ("train", "val", "test")
    }
    keys = [{f.key for f in part} for part in parts.values()]
    assert all(keys) and not (keys[0] & keys[1] or keys[0] & keys[2] or keys[1] & keys[2])
    assert sum(len(k) for k in keys) == len(frames)
    assert select_split(frames, "all", config, lambda: positions) == frames


def test_mission_hold_out():
    a, pa = grid_frames("urban_1", n=3)
    b, pb = grid_frames("rural_1", n=3)
    c, pc = grid_frames("urban_high_1", n=3)
    config = SplitConfig(val_missions=["rural_1"], test_missions=["urban_high"])
    splits = assign_blocks(a + b + c, np.vstack([pa, pb, pc]), config)
    assert splits == ["train"] * len(a) + ["val"] * len(b) + ["test"] * len(c)


def test_split_file(tmp_path):
    frames, positions = grid_frames(n=3)
    (tmp_path / "val.txt").write_text(
        "# published split\n003_urban_1/45deg_low_h/000004\n\n"
        "003_urban_1/left_rgb/90deg_high_h/000002.jpg  # a file path works too\n"
    )
    chosen = select_split(frames, tmp_path / "val.txt", SplitConfig(), lambda: positions)
    assert [f.key for f in chosen] == [
        "003_urban_1/45deg_low_h/000004",
        "003_urban_1/90deg_high_h/000002",
    ]


def test_split_errors(tmp_path):
    frames, positions = grid_frames(n=2)
    (tmp_path / "s.txt").write_text("003_urban_1/45deg_low_h/999999\n")
    with pytest.raises(ValueError, match=r"1 frame\(s\) of split file .*s\.txt are not in"):
        select_split(frames, tmp_path / "s.txt", SplitConfig(), lambda: positions)
    (tmp_path / "bad.txt").write_text("just-a-name\n")
    with pytest.raises(ValueError, match=r"bad\.txt:1: 'just-a-name' is not a frame"):
        read_split_file(tmp_path / "bad.txt")
    with pytest.raises(ValueError, match=r"unknown split 'training'"):
        select_split(frames, "training", SplitConfig(), lambda: positions)
    with pytest.raises(FileNotFoundError, match=r"split file not found"):
        select_split(frames, tmp_path / "none.txt", SplitConfig(), lambda: positions)
    with pytest.raises(ValueError, match=r"block_size must be a positive number of metres, got 0"):
        SplitConfig(block_size=0)
    with pytest.raises(ValueError, match=r"fractions must be three"):
        SplitConfig(fractions=(0.5, 0.5))
    (tmp_path / "empty.txt").write_text("# nothing yet\n\n")
    with pytest.raises(ValueError, match=r"split file .*empty\.txt lists no frame"):
        select_split(frames, tmp_path / "empty.txt", SplitConfig(), lambda: positions)
    with pytest.raises(ValueError, match=r"held out as both val and test"):
        SplitConfig(val_missions=["urban_1"], test_missions=["003_urban_1"])


@pytest.mark.parametrize(
    ("fractions", "message"),
    [
        ((float("nan"), 0.5, 0.5), r"finite and non-negative, got \(nan, 0\.5, 0\.5\)"),
        ((float("inf"), 0.0, 0.0), r"finite and non-negative"),
        ((1.2, -0.1, -0.1), r"finite and non-negative"),
        ((0.8, 0.1, 0.2), r"sum to 1\.1, not 1"),  # no silent rescaling to 73/9/18 %
        ((7, 1.5, 1.5), r"sum to 10, not 1"),
        (("0.7", 0.15, 0.15), r"three numbers"),
        ((True, 0, 0), r"three numbers"),
        (0.7, r"three numbers"),
    ],
)
def test_bad_fractions(fractions, message):
    with pytest.raises(ValueError, match=message):
        SplitConfig(fractions=fractions)


def test_good_fractions_and_block_size():
    assert SplitConfig(fractions=[0.7, 0.2, 0.1]).fractions == (0.7, 0.2, 0.1)
    assert SplitConfig(fractions=(1 / 3, 1 / 3, 1 / 3)).fractions[0] == 1 / 3
    for bad in (float("nan"), float("inf"), -5.0, "150"):
        with pytest.raises(ValueError, match=r"block_size must be a positive number"):
            SplitConfig(block_size=bad)


def test_a_single_mission_string_is_one_mission():
    # Before: "urban_1" was iterated as the characters u, r, b, ... (unknown missions).
    config = SplitConfig(test_missions="urban_1", val_missions="rural_1")
    assert config.test_missions == ("urban_1",) and config.val_missions == ("rural_1",)
    a, pa = grid_frames("urban_1", n=2)
    b, pb = grid_frames("rural_1", n=2)
    c, pc = grid_frames("highway_1", n=2)
    splits = assign_blocks(a + b + c, np.vstack([pa, pb, pc]), config)
    assert splits == ["test"] * len(a) + ["val"] * len(b) + ["train"] * len(c)
    with pytest.raises(ValueError, match=r"unknown ClaraVid mission 'urbn_1'"):
        SplitConfig(test_missions="urbn_1")


def test_the_seed_alone_changes_the_split():
    # Same block size and fractions, only the seed differs (a seed ignored would pass the
    # determinism test above, whose second config also changes the fractions).
    frames, positions = grid_frames()
    fractions = (0.6, 0.2, 0.2)
    three = assign_blocks(frames, positions, SplitConfig(100.0, fractions=fractions, seed=3))
    four = assign_blocks(frames, positions, SplitConfig(100.0, fractions=fractions, seed=4))
    assert three != four


def test_a_split_file_with_a_byte_order_mark(tmp_path):
    # Windows editors write a UTF-8 BOM; it was read as part of the first frame's mission.
    frames, positions = grid_frames("rural_1", n=2)
    (tmp_path / "val.txt").write_text("001_rural_1/45deg_low_h/000000\n", encoding="utf-8-sig")
    chosen = select_split(frames, tmp_path / "val.txt", SplitConfig(), lambda: positions)
    assert [f.key for f in chosen] == ["001_rural_1/45deg_low_h/000000"]


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"seed": -1}, r"^split_config\.seed must be an integer >= 0, got -1$"),
        ({"seed": "1"}, r"^split_config\.seed must be an integer >= 0, got '1' \(a string"),
        ({"seed": 1.5}, r"^split_config\.seed must be an integer"),
        ({"seed": True}, r"^split_config\.seed must be an integer"),
        ({"block_size": 0}, r"^split_config\.block_size must be a positive number"),
        ({"fractions": (0.5, 0.5)}, r"^split_config\.fractions must be three numbers"),
        ({"test_missions": "urbn_1"}, r"^split_config\.test_missions holds unknown ClaraVid"),
        ({"val_missions": [1]}, r"^split_config\.val_missions must be mission names"),
        ({"test_mission": "urban_1"}, r"unknown split_config key\(s\) \['test_mission'\]"),
    ],
)
def test_split_config_errors_name_the_setting(values, message):
    from claravid.data.splits import SplitConfigError, make_split_config

    with pytest.raises(SplitConfigError, match=message):
        make_split_config(values, "split_config.")
    if "test_mission" not in values:  # the training config's spelling
        with pytest.raises(ValueError, match=message.replace(r"split_config\.", r"data\.split\.")):
            make_split_config(values, "data.split.")


def test_a_single_string_and_a_seed_are_normalised():
    from claravid.data.splits import make_split_config

    config = make_split_config({"test_missions": "urban_high_1", "seed": np.int64(3)})
    assert config.test_missions == ("urban_high_1",) and config.seed == 3
    assert type(config.seed) is int


def test_a_held_out_mission_outside_the_selection_is_named():
    a, pa = grid_frames("urban_1", n=2)
    config = SplitConfig(test_missions="urban_high_1")
    with pytest.warns(UserWarning, match=r"008_urban_dense_1 \(test_missions\).*\(003_urban_1\)"):
        test = select_split(a, "test", config, lambda: pa)
    assert test == []


def test_a_block_larger_than_the_mission_is_one_block():
    # Before: the grid was anchored at the world origin, so a mission around (0, 0) was cut
    # into four blocks however large they were.
    from claravid.data.splits import block_ids

    frames, positions = grid_frames("urban_1", n=4)
    centred = positions - positions.mean(axis=0)
    assert len(set(block_ids(frames, centred, 1e9))) == 1
    # Anchored at the mission's minimum camera x and y: blocks count from 0.
    assert set(block_ids(frames, centred, 100.0)) == {
        f"003_urban_1/{x}_{y}" for x in (0, 1) for y in (0, 1)
    }


def _blocks_of(xs, ys, block_size=150.0):
    from claravid.data.splits import block_ids

    frames = [Frame("urban_1", "low", "h", f"{i:06d}", {}) for i in range(len(xs))]
    names = block_ids(frames, np.column_stack([xs, ys]), block_size)
    return [name.split("/")[1] for name in names]


def test_an_extent_of_exact_blocks_puts_the_far_edge_in_the_last_block():
    """x spans 300 m = 2 blocks of 150, y 150 m = 1 block: the rule (docs/data.md, "Where the
    blocks lie") gives floor(300 / 150) + 1 = 3 columns and 2 rows, centred on the extent, so
    the grid starts 75 m before the first camera: x origin 100 - 75 = 25, y origin -50 - 75 =
    -125. The far edge, x = 400 (column floor(375 / 150) = 2) and y = 100 (row floor(225 / 150)
    = 1), falls in the last column and row with its neighbours, never in a block of its own."""
    xs = [100.0, 174.9, 175.0, 250.0, 324.9, 325.0, 399.0, 400.0, 400.0]
    ys = [-50.0, -50.0, 24.9, 25.0, 100.0, 99.0, 100.0, -50.0, 100.0]
    assert _blocks_of(xs, ys) == ["0_0", "0_0", "1_0", "1_1", "1_1", "2_1", "2_1", "2_0", "2_1"]


def test_an_exact_extent_in_decimal_metres_is_not_cut_by_rounding():
    """187.8 to 637.8 is 450 m, 3 blocks, in the metres the extrinsics hold; in binary floating
    point 637.8 - 187.8 is a hair under 450, and the grid came out one column short, leaving
    the cameras at x = 637.8 alone in a fourth column outside it. By the rule: 4 columns from
    412.8 - 300 = 112.8, so 600.0 (3.25 blocks in) and 637.8 (3.5) share column 3; in y, 20.1 to
    170.1 is 1 block: 2 rows from 95.1 - 150 = -54.9."""
    xs = [187.8, 262.7, 262.9, 487.8, 562.7, 600.0, 637.8, 637.8]
    ys = [20.1, 170.1, 20.1, 95.0, 95.2, 170.1, 20.1, 170.1]
    assert 637.8 - 187.8 != 450.0  # what the floating point makes of it
    assert _blocks_of(xs, ys) == ["0_0", "0_1", "1_0", "2_0", "2_1", "3_1", "3_0", "3_1"]
