"""Palettes: the shipped tables, the UAVid reduction pixel by pixel, and bad YAML."""

import numpy as np
import pytest
import yaml

from claravid.data.palettes import PaletteError, load_palette, palette_from_dict
from claravid.io.labels import UNKNOWN_CODE, label_codes
from claravid.io.layout import CLASS_BY_NAME, CLASSES

CLARAVID_TRAIN_IDS = {0: 0, 1: 1, 2: 2, 3: 3, 4: 4, 5: 5, 6: 6, 7: 7, 8: 8, 9: 9, 10: 10,
                      13: 11, 14: 12, 15: 13, 16: 14, 17: 15, 18: 16, 19: 17, 22: 18}  # fmt: skip

UAVID = {"Clutter": 0, "Building": 1, "Road": 2, "Static car": 3, "Tree": 4,
         "Low vegetation": 5, "Human": 6, "Moving car": 7}  # fmt: skip
UAVID_FROM = {
    "Building": "Building", "RoadLine": "Road", "Road": "Road", "Bridge": "Road",
    "Vegetation": "Tree", "Terrain": "Low vegetation", "Pedestrian": "Human",
    "Vehicles": "Static car", "Fence": "Clutter", "Wire": "Clutter", "Pole": "Clutter",
    "SideWalk": "Clutter", "TrafficSign": "Clutter", "GreenEnergy": "Clutter",
    "GuardRail": "Clutter", "Urban props": "Clutter", "Water": "Clutter", "Tent": "Clutter",
    "Constr props": "Clutter",
}  # fmt: skip


def remap(palette, semantic, dynamic=None):
    return palette.remap(label_codes(np.asarray(semantic, np.uint8), dynamic))


def test_claravid_palette_train_ids():
    palette = load_palette("claravid")
    assert palette.num_classes == 19 and not palette.uses_dynamic
    for class_id, train_id in CLARAVID_TRAIN_IDS.items():
        assert remap(palette, [[class_id]])[0, 0] == train_id
    for unknown in (11, 12, 20, 21, 23, 128, 200, 254, 255):
        assert remap(palette, [[unknown]])[0, 0] == 255
    assert palette.names[11] == "GreenEnergy" and palette.colors[18].tolist() == [150, 100, 100]


def test_uavid_reduction_every_class_static_and_dynamic():
    palette = load_palette("uavid")
    assert palette.num_classes == 8 and palette.uses_dynamic
    assert palette.colors[UAVID["Moving car"]].tolist() == [64, 0, 128]
    for cls in CLASSES:
        static = remap(palette, [[cls.id]], np.array([[255]], np.uint8))[0, 0]
        dynamic = remap(palette, [[cls.id]], np.array([[0]], np.uint8))[0, 0]
        if cls.name == "Unlabeled":
            assert static == dynamic == 255
            continue
        assert static == UAVID[UAVID_FROM[cls.name]], cls.name
        expected_dynamic = "Moving car" if cls.name == "Vehicles" else UAVID_FROM[cls.name]
        assert dynamic == UAVID[expected_dynamic], cls.name


def test_unknown_ids_are_ignored_in_both_palettes():
    semantic = np.array([[11, 9, 254, 22]], np.uint8)
    codes = label_codes(semantic, np.array([[0, 0, 0, 255]], np.uint8))
    assert codes[0, 0] == UNKNOWN_CODE and codes[0, 2] == UNKNOWN_CODE
    assert load_palette("uavid").remap(codes).tolist() == [[255, 7, 255, 2]]
    assert load_palette("claravid").remap(codes).tolist() == [[255, 9, 255, 18]]


def test_user_palette_from_yaml_path(tmp_path):
    config = {
        "name": "binary",
        "classes": [
            {"id": 0, "name": "background", "color": [0, 0, 0]},
            {"id": 1, "name": "vehicle", "color": [255, 0, 0]},
        ],
        "mapping": {c.name: "background" for c in CLASSES if c.name != "Unlabeled"}
        | {"Vehicles": "vehicle", "Water": "ignore"},
    }
    path = tmp_path / "binary.yaml"
    path.write_text(yaml.safe_dump(config))
    palette = load_palette(path)
    ids = [CLASS_BY_NAME[n].id for n in ("Vehicles", "Road", "Water")]
    assert remap(palette, [ids]).tolist() == [[1, 0, 255]]


BASE = {"name": "p", "classes": [{"id": 0, "name": "a", "color": [1, 2, 3]}]}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"mapping": {"Buildingz": "a"}}, r"'Buildingz': not a ClaraVid class"),
        ({"mapping": {"Building": "b"}}, r"'Building': 'b' is not a class of this palette"),
        (
            {
                "classes": [
                    {"id": 0, "name": "a", "color": [0, 0, 0]},
                    {"id": 0, "name": "b", "color": [0, 0, 0]},
                ]
            },
            r"duplicate id 0 \('a' and 'b'\)",
        ),
        ({"classes": [{"id": 1, "name": "a", "color": [0, 0, 0]}]}, r"without gaps"),
        ({"classes": [{"id": 0, "name": "a", "color": [0, 0]}]}, r"colour"),
        ({"mapping": {"Building": "a"}}, r"leaves \['Fence'.*unmapped"),
        ({"dynamic": {"Vehicles": "zzz"}}, r"'dynamic' entry 'Vehicles'"),
        ({"colours": []}, r"unknown key"),
        ({"classes": [{"id": 0, "name": "a", "color": [0.5, 2, 3]}]}, r"'a' colour \[0\.5, 2, 3\]"),
        ({"classes": [{"id": 0, "name": "a", "color": [True, 2, 3]}]}, r"'a' colour \[True"),
        ({"classes": [{"id": 0, "name": None, "color": [1, 2, 3]}]}, r"entry 1 has name None"),
        ({"classes": [{"id": 0.0, "name": "a", "color": [1, 2, 3]}]}, r"'a' has id 0\.0"),
        ({"name": None}, r"'name' is None"),
        ({"mapping": {"Building": ["a"]}}, r"'Building': \['a'\] is not a palette class"),
    ],
)
def test_bad_palette_names_the_entry(change, message):
    config = {**BASE, "mapping": {c.name: "a" for c in CLASSES if c.name != "Unlabeled"}}
    config.update(change)
    with pytest.raises(PaletteError, match=message):
        palette_from_dict(config, "p.yaml")


def test_unknown_palette_name_and_bad_yaml(tmp_path):
    with pytest.raises(
        PaletteError,
        match=r"unknown palette 'cityscapes'.*aeroscapes, claravid, syndrone, uavid, udd6, vdd",
    ):
        load_palette("cityscapes")
    (tmp_path / "bad.yaml").write_text("classes: [unclosed")
    with pytest.raises(PaletteError, match=r"bad\.yaml: not valid YAML"):
        load_palette(tmp_path / "bad.yaml")
    with pytest.raises(PaletteError, match=r"not found: .*missing\.yaml"):
        load_palette(tmp_path / "missing.yaml")


def test_colorize():
    palette = load_palette("uavid")
    out = palette.colorize(np.array([[1, 255]]))
    assert out.tolist() == [[[128, 0, 0], [0, 0, 0]]]


PALETTE_YAML = """\
name: twice
classes:
  - {id: 0, name: a, color: [1, 2, 3]}
  - {id: 1, name: b, color: [4, 5, 6]}
mapping:
%s
"""


def _mapping_lines(extra=""):
    names = [c.name for c in CLASSES if c.name != "Unlabeled"]
    return "\n".join(f"  {n}: a" for n in names) + extra


def test_duplicate_yaml_keys_are_errors_naming_the_key(tmp_path):
    path = tmp_path / "twice.yaml"
    path.write_text(PALETTE_YAML % _mapping_lines())
    assert load_palette(path).num_classes == 2  # the file is valid without the duplicate
    # Building given twice: PyYAML alone would silently keep the second line (b).
    path.write_text(PALETTE_YAML % _mapping_lines("\n  Building: b"))
    with pytest.raises(
        PaletteError,
        match=r"twice\.yaml: duplicate key 'Building' \(first on line 6, again on line 25",
    ):
        load_palette(path)
    # At any depth: inside a class entry too.
    path.write_text(
        (PALETTE_YAML % _mapping_lines()).replace("{id: 1, name: b,", "{id: 1, name: b, id: 2,")
    )
    with pytest.raises(PaletteError, match=r"twice\.yaml: duplicate key 'id'"):
        load_palette(path)
    path.write_text(PALETTE_YAML.replace("name: twice", "name: twice\nname: thrice") % "")
    with pytest.raises(PaletteError, match=r"duplicate key 'name'"):
        load_palette(path)


def test_binary_palette_file_is_an_error_naming_it(tmp_path):
    path = tmp_path / "image.yaml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")
    with pytest.raises(PaletteError, match=r"image\.yaml: not a YAML text file \(binary"):
        load_palette(path)
    path.write_bytes(b"name: \xff\xfe")
    with pytest.raises(PaletteError, match=r"image\.yaml: not a YAML text file"):
        load_palette(path)


# The real datasets' ids, and our reduction of every ClaraVid class written out.
UDD6 = ["Other", "Facade", "Road", "Vegetation", "Vehicle", "Roof"]
VDD = ["Other", "Wall", "Road", "Vegetation", "Vehicle", "Roof", "Water"]
AEROSCAPES = ["Background", "Person", "Bike", "Car", "Drone", "Boat", "Animal", "Obstacle",
              "Construction", "Vegetation", "Road", "Sky"]  # fmt: skip
OTHER = ["Fence", "Wire", "Pedestrian", "Pole", "SideWalk", "TrafficSign", "GreenEnergy",
         "GuardRail", "Urban props", "Tent", "Constr props"]  # fmt: skip
UDD6_FROM = {"Building": "Roof", "Road": "Road", "RoadLine": "Road", "Bridge": "Road",
             "Vegetation": "Vegetation", "Terrain": "Vegetation", "Vehicles": "Vehicle",
             "Water": "Other"} | dict.fromkeys(OTHER, "Other")  # fmt: skip
VDD_FROM = UDD6_FROM | {"Water": "Water"}
AEROSCAPES_FROM = {
    "Building": "Construction", "Bridge": "Construction", "Tent": "Construction",
    "Constr props": "Construction", "Pedestrian": "Person", "Vehicles": "Car", "Road": "Road",
    "RoadLine": "Road", "SideWalk": "Road", "Vegetation": "Vegetation", "Terrain": "Vegetation",
    "Fence": "Obstacle", "Wire": "Obstacle", "Pole": "Obstacle", "TrafficSign": "Obstacle",
    "GuardRail": "Obstacle", "GreenEnergy": "Obstacle", "Urban props": "Obstacle",
    "Water": "Background",
}  # fmt: skip


@pytest.mark.parametrize(
    ("name", "classes", "reduction"),
    [
        ("udd6", UDD6, UDD6_FROM),
        ("vdd", VDD, VDD_FROM),
        ("aeroscapes", AEROSCAPES, AEROSCAPES_FROM),
    ],
)
def test_real_target_palettes(name, classes, reduction):
    palette = load_palette(name)
    assert palette.name == name and list(palette.names) == classes
    assert not palette.uses_dynamic
    checked = 0
    for cls in CLASSES:
        got = remap(palette, [[cls.id]], np.array([[0]], np.uint8))[0, 0]  # dynamic: same
        if cls.name == "Unlabeled":
            assert got == 255
            continue
        assert got == classes.index(reduction[cls.name]), cls.name
        checked += 1
    assert checked == 19


def test_udd6_colours_are_the_datasets():
    colours = load_palette("udd6").colors.tolist()
    assert colours == [[0, 0, 0], [102, 102, 156], [128, 64, 128], [107, 142, 35], [0, 0, 142],
                       [70, 70, 70]]  # fmt: skip
