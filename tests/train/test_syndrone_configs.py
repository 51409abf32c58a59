"""The shipped syndrone configs: train on ClaraVid with the coarse palette, validate on each real
dataset's own layout and labels through the same palette."""

import pytest

from claravid.data.real_layouts import RealSegmentation
from claravid.data.targets import UAVidSegmentation
from claravid.train.config import load_config
from claravid.train.data import build_val_dataset
from claravid.train.loop import _validation_data
from tests.helpers.real_trees import make_tree

# (dataset, split the config validates on): ICG has labels for its training set only.
CONFIGS = [("uavid", "val"), ("udd5", "val"), ("udd6", "val"), ("vdd", "val"),
           ("aeroscapes", "val"), ("icg", "train")]  # fmt: skip


@pytest.mark.parametrize(("dataset", "split"), CONFIGS)
def test_each_config_validates_on_its_real_dataset_through_syndrone(tmp_path, dataset, split):
    make_tree(tmp_path, dataset)
    cfg = load_config(f"claravid_syndrone_to_{dataset}", [f"data.val_root={tmp_path}"])
    assert (cfg.data.palette, cfg.data.val_dataset, cfg.data.val_split) == (
        "syndrone", dataset, split)  # fmt: skip
    val_set = build_val_dataset(cfg)
    kind = UAVidSegmentation if dataset == "uavid" else RealSegmentation
    assert isinstance(val_set, kind) and len(val_set) == 2 + 2 * (dataset == "icg")
    _, palette = _validation_data(cfg, [], print)  # the labels' fit is checked here
    assert palette.name == "syndrone" and val_set.palette.name == "syndrone"
    assert int(val_set[0]["mask"].max()) <= 6 or int(val_set[0]["mask"].max()) == 255


def test_a_syndrone_config_pointed_at_the_wrong_tree_stops(tmp_path):
    make_tree(tmp_path, "udd5")
    cfg = load_config("claravid_syndrone_to_udd6", [f"data.val_root={tmp_path}"])
    with pytest.raises(ValueError, match="this is a UDD5 tree"):
        _validation_data(cfg, [], print)
