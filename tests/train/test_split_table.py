"""The training log's table of realised split shares (claravid.train.data.split_table)."""

from collections import Counter

import pytest

from claravid import ClaraVidSegmentation
from claravid.data.splits import SplitBalanceWarning
from claravid.train import load_config
from claravid.train.data import build_train_dataset, split_table
from tests.tiny import tiny


def test_split_table_shows_the_shares_the_splits_hold(claravid_root, tmp_path):
    cfg = load_config("demo", tiny(claravid_root, tmp_path / "run", "data.split.block_size=80"))
    config = {"block_size": 80.0}
    # 80 m blocks leave rural_1 without val frames: the warning says so (75 m would not).
    with pytest.warns(SplitBalanceWarning, match=r"001_rural_1 \(5 block\(s\): 83/0/17 %\)"):
        table = split_table(build_train_dataset(cfg))
        held = {
            s: Counter(
                f.mission
                for f in ClaraVidSegmentation(claravid_root, s, split_config=config).frames
            )
            for s in ("train", "val", "test")
        }
    total = sum(sum(c.values()) for c in held.values())
    overall = " ".join(f"{100 * sum(held[s].values()) / total:6.1f}" for s in held)
    assert table.splitlines()[0].startswith("split shares (80 m blocks, seed 0")
    assert table.splitlines()[-1].endswith(overall) and f" {total:6d} " in table.splitlines()[-1]
    rural = " ".join(f"{100 * held[s]['rural_1'] / 18:6.1f}" for s in held)
    assert any(
        line.split()[0] == "001_rural_1" and line.endswith(rural) for line in table.splitlines()
    )


def test_no_table_for_a_split_file_or_uavid(claravid_root, tmp_path, uavid_root):
    listed = tmp_path / "train.txt"
    listed.write_text("001_rural_1/45deg_low_h/000000\n")
    cfg = load_config("demo", tiny(claravid_root, tmp_path / "a", f"data.train_split={listed}"))
    assert split_table(build_train_dataset(cfg)) is None
    cfg = load_config(
        "demo", tiny(uavid_root, tmp_path / "b", "data.dataset=uavid", "data.palette=uavid")
    )
    assert split_table(build_train_dataset(cfg)) is None
