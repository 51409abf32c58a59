"""The syndrone palette equals SynDrone's coarse protocol (docs/data.md), decoded from generated
trees of the six real datasets and from ClaraVid label codes.

The expected tables below are written out from the protocol's statement, by class name, not
read from configs/palettes/syndrone.yaml or claravid/data/real_classes.py.
"""

import numpy as np
import pytest

from claravid.data.palettes import load_palette
from claravid.data.real_layouts import RealSegmentation
from claravid.data.targets import UAVidSegmentation
from claravid.io.labels import DYNAMIC_OFFSET
from tests.helpers.real_trees import make_tree

# Coarse classes: (id, name, colour).
COARSE = [
    (0, "Road", (128, 64, 128)),
    (1, "Nature", (107, 142, 35)),
    (2, "Person", (220, 20, 60)),
    (3, "Vehicle", (0, 0, 142)),
    (4, "Construction", (70, 70, 70)),
    (5, "Obstacle", (153, 153, 153)),
    (6, "Water", (45, 60, 150)),
]
ID = {name: i for i, name in [(c[0], c[1]) for c in COARSE]}
X = None  # ignore

# Real dataset class -> coarse class (X: ignore), as the protocol states them.
REAL = {
    "uavid": {"Clutter": X, "Building": "Construction", "Road": "Road",
              "Static car": "Vehicle", "Moving car": "Vehicle", "Tree": "Nature",
              "Low vegetation": "Nature", "Human": "Person"},
    "udd5": {"Vegetation": "Nature", "Building": "Construction", "Road": "Road",
             "Vehicle": "Vehicle", "Other": X},
    "udd6": {"Other": X, "Facade": "Construction", "Roof": "Construction", "Road": "Road",
             "Vegetation": "Nature", "Vehicle": "Vehicle"},
    # VDD by class name (NOT SynDrone's released {0:0, 1:4, 2:-1, 3:3, 4:4, 5:6, 6:-1}).
    "vdd": {"other": X, "wall": "Construction", "roof": "Construction", "road": "Road",
            "vegetation": "Nature", "vehicle": "Vehicle", "water": "Water"},
    "aeroscapes": {"background": X, "drone": X, "boat": X, "animal": X, "sky": X,
                   "person": "Person", "bike": "Vehicle", "car": "Vehicle",
                   "obstacle": "Obstacle", "construction": "Construction",
                   "vegetation": "Nature", "road": "Road"},
    "icg": {"unlabeled": X, "dog": X, "ar-marker": X, "conflicting": X, "paved-area": "Road",
            "dirt": "Nature", "grass": "Nature", "gravel": "Nature", "rocks": "Nature",
            "vegetation": "Nature", "tree": "Nature", "bald-tree": "Nature", "water": "Water",
            "pool": "Water", "roof": "Construction", "wall": "Construction",
            "window": "Construction", "door": "Construction", "fence": "Construction",
            "fence-pole": "Construction", "person": "Person", "car": "Vehicle",
            "bicycle": "Vehicle", "obstacle": "Obstacle"},
}  # fmt: skip

# ClaraVid class id -> coarse class: the protocol's analogy, then (last three) the toolkit's
# stated choice for the classes without an analogue.
CLARAVID = {0: "Construction", 1: "Construction", 22: "Construction", 2: "Obstacle",
            4: "Obstacle", 10: "Obstacle", 14: "Obstacle", 15: "Obstacle", 6: "Road",
            5: "Road", 7: "Road", 8: "Nature", 17: "Nature", 3: "Person", 9: "Vehicle",
            16: "Water",
            13: "Obstacle", 18: "Construction", 19: "Obstacle"}  # fmt: skip


def expected_ids(names: list[str], dataset: str) -> np.ndarray:
    table = REAL[dataset]
    return np.asarray([255 if table[n] is None else ID[table[n]] for n in names], np.uint8)


def test_the_coarse_classes_are_the_protocols():
    palette = load_palette("syndrone")
    assert palette.names == tuple(c[1] for c in COARSE)
    assert [tuple(int(v) for v in c) for c in palette.colors] == [c[2] for c in COARSE]
    assert set(palette.datasets) == set(REAL)
    assert set(palette.no_analogue) == {"GreenEnergy", "Tent", "Constr props"}


def test_claravid_codes_map_by_the_analogy_static_and_dynamic():
    palette = load_palette("syndrone")
    codes = np.arange(256, dtype=np.uint8).reshape(16, 16)  # every code, non-trivial shape
    got = palette.remap(codes).ravel()
    for class_id in range(256):
        if class_id < DYNAMIC_OFFSET:
            want = CLARAVID.get(class_id)
        else:
            want = CLARAVID.get(class_id - DYNAMIC_OFFSET)
        assert got[class_id] == (255 if want is None else ID[want]), class_id
    # Unused ClaraVid ids and Unlabeled are ignore.
    assert all(got[i] == 255 for i in (11, 12, 20, 21, 255))


@pytest.mark.parametrize("dataset", ["udd5", "udd6", "vdd", "aeroscapes", "icg"])
def test_real_masks_decode_to_the_protocols_classes(tmp_path, dataset):
    truth = make_tree(tmp_path, dataset)
    ds = RealSegmentation(tmp_path, dataset, split="all", palette="syndrone")
    assert len(ds) == len(truth)
    for i, mask_path in enumerate(ds.masks):
        names = truth[mask_path.relative_to(tmp_path).as_posix()]
        got = ds.read_mask(i).numpy().ravel()
        np.testing.assert_array_equal(got, expected_ids(names, dataset), err_msg=str(mask_path))
    assert ds[0]["mask"].shape == (20, 28)


def test_uavid_colour_labels_decode_to_the_protocols_classes(tmp_path):
    truth = make_tree(tmp_path, "uavid")
    ds = UAVidSegmentation(tmp_path, split="all", palette="syndrone")
    assert len(ds) == 4
    for i, image in enumerate(ds.images):
        label = ds.label_path(image).relative_to(tmp_path).as_posix()
        got = ds[i]["mask"].numpy().ravel()
        np.testing.assert_array_equal(got, expected_ids(truth[label], "uavid"), err_msg=label)
