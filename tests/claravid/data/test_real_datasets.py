"""UDD5, UDD6, VDD, AeroScapes and ICG trees: splits, the wrong dataset told from its ids or
colours, and a palette's real side refused when it is wrong (one line naming file and key)."""

import shutil
import warnings

import cv2
import numpy as np
import pytest

from claravid.data.masks import DatasetMismatchWarning, check_palette_fit
from claravid.data.palettes import PaletteError, load_palette
from claravid.data.real_layouts import RealSegmentation, list_pairs
from claravid.io.yamlfile import load_yaml
from tests.helpers.real_trees import make_tree


@pytest.mark.parametrize(
    ("dataset", "counts"),
    [
        ("udd5", {"train": 2, "val": 2, "all": 4}),
        ("vdd", {"train": 2, "val": 2, "all": 4}),  # no test/ in this copy: all = train + val
        ("aeroscapes", {"train": 2, "val": 2, "all": 4}),
        ("icg", {"train": 4, "all": 4}),
    ],
)
def test_each_split_holds_its_own_images(tmp_path, dataset, counts):
    make_tree(tmp_path, dataset)
    seen = {s: [img for img, _ in list_pairs(tmp_path, dataset, s)] for s in counts}
    assert {s: len(v) for s, v in seen.items()} == counts
    if "val" in counts:
        assert not set(seen["train"]) & set(seen["val"])
        assert set(seen["all"]) == set(seen["train"]) | set(seen["val"])


def test_icg_has_no_val_split_and_says_which_it_has(tmp_path):
    make_tree(tmp_path, "icg")
    with pytest.raises(ValueError, match="no labelled 'val' split; use train, all"):
        RealSegmentation(tmp_path, "icg", split="val")


def test_a_missing_mask_is_named(tmp_path):
    make_tree(tmp_path, "udd6")
    (tmp_path / "val" / "gt" / "DJI_val_0001.png").unlink()
    with pytest.raises(FileNotFoundError, match="DJI_val_0001"):
        RealSegmentation(tmp_path, "udd6", split="val", palette="syndrone")


def test_udd6_read_of_a_udd5_tree_says_so_in_one_line(tmp_path):
    make_tree(tmp_path, "udd5")
    ds = RealSegmentation(tmp_path, "udd6", split="all", palette="syndrone")
    for palette in (ds.palette, load_palette("udd6")):
        with pytest.raises(ValueError, match="this is a UDD5 tree") as error:
            check_palette_fit(ds.masks, palette, dataset="udd6")
        assert "\n" not in str(error.value) and "--dataset udd5" in str(error.value)
    # A folder read in the udd6 palette (masks may be anyone's ids 0..5): a warning only.
    with pytest.warns(DatasetMismatchWarning, match="this may be a UDD5 tree"):
        check_palette_fit(ds.masks, load_palette("udd6"))
    # ... and only from three label maps or more: two without Roof may lack it by chance.
    assert len(ds.masks) >= 3
    with warnings.catch_warnings():
        warnings.simplefilter("error", DatasetMismatchWarning)
        check_palette_fit(ds.masks[:2], load_palette("udd6"))


def test_udd5_read_of_a_udd6_tree_says_so(tmp_path):
    make_tree(tmp_path, "udd6")
    ds = RealSegmentation(tmp_path, "udd5", split="train")
    with pytest.raises(ValueError, match="this is a UDD6 tree"):
        check_palette_fit(ds.masks, ds.palette, dataset="udd5")


def test_a_udd6_tree_read_as_udd6_passes(tmp_path):
    make_tree(tmp_path, "udd6")
    ds = RealSegmentation(tmp_path, "udd6", split="all", palette="syndrone")
    check_palette_fit(ds.masks, ds.palette, dataset="udd6")


def test_a_colour_tree_of_another_dataset_is_named_from_its_colours(tmp_path):
    make_tree(tmp_path, "icg")
    masks = sorted((tmp_path / "training_set").rglob("label_images/*.png"))
    with pytest.raises(ValueError, match="UAVid does not have; they are icg labels") as error:
        check_palette_fit(masks, load_palette("syndrone"), dataset="uavid")
    assert str(masks[0]) in str(error.value)


def test_an_index_tree_of_another_dataset_is_named_from_its_ids(tmp_path):
    make_tree(tmp_path, "aeroscapes")  # ids 0..11: VDD has 0..6
    masks = sorted((tmp_path / "SegmentationClass").glob("*.png"))
    with pytest.raises(ValueError, match="VDD does not have; they are aeroscapes labels"):
        check_palette_fit(masks, load_palette("syndrone"), dataset="vdd")


@pytest.mark.parametrize(
    ("dataset", "palette"), [("udd5", "udd6"), ("vdd", "claravid"), ("udd6", "uavid")]
)
def test_a_shipped_palette_of_other_classes_is_refused(tmp_path, dataset, palette):
    # UDD5's ids read as UDD6's, or VDD's as ClaraVid's, would all be "known" and wrong.
    make_tree(tmp_path, dataset)
    with pytest.raises(PaletteError, match=f"real side covers {dataset}"):
        RealSegmentation(tmp_path, dataset, palette=palette)


def test_icg_class_dict_with_a_colour_twice_is_named(tmp_path):
    make_tree(tmp_path, "icg")
    csv = tmp_path / "training_set" / "gt" / "semantic" / "class_dict.csv"
    csv.write_text(csv.read_text().replace("dirt, 130, 76, 0", "dirt, 128, 64, 128"))
    with pytest.raises(ValueError, match=r"class_dict.csv line 4: colour \[128, 64, 128\] listed"):
        RealSegmentation(tmp_path, "icg")


# --- the palette's real side: one line naming the file and the key -------------------------


def _palette_with(tmp_path, edit):
    """The shipped syndrone palette with ``edit`` applied to its real side, as a YAML file."""
    import yaml

    config = load_yaml(shutil.copy(load_palette_path(), tmp_path / "p.yaml"))
    edit(config["real"])
    path = tmp_path / "edited.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def load_palette_path():
    from claravid.infra.resources import shipped_file

    return str(shipped_file("syndrone", "palettes"))


def _refused(path, *words):
    with pytest.raises(PaletteError) as error:
        load_palette(path)
    message = str(error.value)
    assert "\n" not in message and str(path) in message, message
    for word in words:
        assert word in message, message


def test_a_real_class_the_dataset_does_not_have(tmp_path):
    def edit(real):
        real["udd5"][4]["name"] = "Roof"  # UDD6's, not UDD5's

    _refused(_palette_with(tmp_path, edit), "real.udd5 entry 5", "UDD5 has no class 'Roof'")


def test_one_real_class_given_two_targets(tmp_path):
    def edit(real):
        real["uavid"].append({"name": "Tree", "id": 4, "to": "Road"})

    _refused(_palette_with(tmp_path, edit), "real.uavid entry 9", "'Tree' given twice",
             "Nature and Road")  # fmt: skip


def test_a_colour_listed_twice(tmp_path):
    def edit(real):
        real["icg"][2]["color"] = [128, 64, 128]  # dirt given paved-area's colour

    _refused(_palette_with(tmp_path, edit), "real.icg entry 3",
             "colour [128, 64, 128] listed twice")  # fmt: skip


def test_an_id_that_is_not_the_datasets(tmp_path):
    def edit(real):
        real["vdd"][1]["id"] = 4  # wall is 1 in VDD

    _refused(_palette_with(tmp_path, edit), "real.vdd entry 2", "wall", "VDD gives id 1")


def test_a_real_class_left_unmapped_and_an_unknown_dataset(tmp_path):
    def drop(real):
        del real["aeroscapes"][11]

    _refused(_palette_with(tmp_path, drop), "real.aeroscapes", "['sky'] unmapped")

    def unknown(real):
        real["udd7"] = real["udd6"]

    (tmp_path / "x").mkdir()
    _refused(_palette_with(tmp_path / "x", unknown), "unknown dataset(s) ['udd7']")


def test_a_target_that_is_not_a_palette_class(tmp_path):
    def edit(real):
        real["udd6"][5]["to"] = "Roof"

    _refused(_palette_with(tmp_path, edit), "real.udd6 entry 6", "'Roof' is not a class")


def test_the_shipped_per_dataset_palettes_still_load_without_a_real_side():
    for name in ("uavid", "udd6", "vdd", "aeroscapes", "claravid"):
        palette = load_palette(name)
        assert palette.real == {} and palette.datasets == ()


def test_a_udd6_tree_reads_the_same_ids_through_its_own_palette(tmp_path):
    # The toolkit's own udd6 palette keeps reading UDD6's ids as its train ids (unchanged).
    make_tree(tmp_path, "udd6")
    ds = RealSegmentation(tmp_path, "udd6", split="train")
    assert ds.palette.name == "udd6"
    raw = cv2.imread(str(ds.masks[0]), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(ds.read_mask(0).numpy(), raw)


def test_values_outside_the_dataset_are_ignored_and_counted_in_every_encoding():
    udd6 = load_palette("syndrone").real_map("udd6")
    # ids: 0 Other -> ignore, 5 Roof -> Construction (4), 9 unknown, 255 ignore (not unknown)
    ids, unknown = udd6.decode(np.array([[0, 5, 9, 255]], np.uint8))
    assert ids.tolist() == [[255, 4, 255, 255]] and unknown == 1
    ids, unknown = udd6.decode(np.array([[3, 5, 300, 255, 261]], np.uint16))  # 261: not 5
    assert ids.tolist() == [[1, 4, 255, 255, 255]] and unknown == 2
    rgb = np.array([[[0, 0, 0], [70, 70, 70], [1, 2, 3]]], np.uint8)
    ids, unknown = udd6.decode(rgb)
    assert ids.tolist() == [[255, 4, 255]] and unknown == 1
    vdd = load_palette("syndrone").real_map("vdd")  # VDD publishes ids only
    assert vdd.decode(rgb)[1] == 3
