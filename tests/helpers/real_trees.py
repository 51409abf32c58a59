"""Tiny trees of the real UAV datasets, laid out as the releases are, for the readers' tests.

The class tables below are written out from the datasets' own publications (UAVid's colours,
UDD's ids and colours, VDD's and AeroScapes' ids, the Semantic Drone Dataset's class_dict.csv),
independently of ``claravid/data/real_classes.py``. Every mask holds every class of its
dataset, so a table entry that is wrong shows in any file. Images are non-square (20×28).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

HEIGHT, WIDTH = 20, 28

# name -> (id, colour); None where the dataset does not publish it.
UAVID = {"Clutter": (0, (0, 0, 0)), "Building": (1, (128, 0, 0)), "Road": (2, (128, 64, 128)),
         "Static car": (3, (192, 0, 192)), "Tree": (4, (0, 128, 0)),
         "Low vegetation": (5, (128, 128, 0)), "Human": (6, (64, 64, 0)),
         "Moving car": (7, (64, 0, 128))}  # fmt: skip
UDD5 = {"Vegetation": (0, (107, 142, 35)), "Building": (1, (102, 102, 156)),
        "Road": (2, (128, 64, 128)), "Vehicle": (3, (0, 0, 142)),
        "Other": (4, (0, 0, 0))}  # fmt: skip
UDD6 = {"Other": (0, (0, 0, 0)), "Facade": (1, (102, 102, 156)), "Road": (2, (128, 64, 128)),
        "Vegetation": (3, (107, 142, 35)), "Vehicle": (4, (0, 0, 142)),
        "Roof": (5, (70, 70, 70))}  # fmt: skip
VDD = {n: (i, None) for i, n in enumerate(
    ["other", "wall", "road", "vegetation", "vehicle", "roof", "water"])}  # fmt: skip
AEROSCAPES = {n: (i, None) for i, n in enumerate(
    ["background", "person", "bike", "car", "drone", "boat", "animal", "obstacle",
     "construction", "vegetation", "road", "sky"])}  # fmt: skip
ICG_CSV = """name, r, g, b
unlabeled, 0, 0, 0
paved-area, 128, 64, 128
dirt, 130, 76, 0
grass, 0, 102, 0
gravel, 112, 103, 87
water, 28, 42, 168
rocks, 48, 41, 30
pool, 0, 50, 89
vegetation, 107, 142, 35
roof, 70, 70, 70
wall, 102, 102, 156
window, 254, 228, 12
door, 254, 148, 12
fence, 190, 153, 153
fence-pole, 153, 153, 153
person, 255, 22, 96
dog, 102, 51, 0
car, 9, 143, 150
bicycle, 119, 11, 32
tree, 51, 51, 0
bald-tree, 190, 250, 190
ar-marker, 112, 150, 146
obstacle, 2, 135, 115
conflicting, 255, 0, 0
"""
ICG = {
    row.split(",")[0].strip(): (None, tuple(int(v) for v in row.split(",")[1:]))
    for row in ICG_CSV.splitlines()[1:]
}
TABLES = {"uavid": UAVID, "udd5": UDD5, "udd6": UDD6, "vdd": VDD, "aeroscapes": AEROSCAPES,
          "icg": ICG}  # fmt: skip


def class_layout(count: int, seed: int) -> np.ndarray:
    """HEIGHT×WIDTH class indices 0..count-1, each present, in a seeded order."""
    rng = np.random.default_rng(seed)
    return rng.permutation(np.resize(np.arange(count), HEIGHT * WIDTH)).reshape(HEIGHT, WIDTH)


def _write(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if array.ndim == 3:
        array = array[..., ::-1]  # RGB -> OpenCV's BGR
    assert cv2.imwrite(str(path), np.ascontiguousarray(array))


def write_pair(image: Path, mask: Path, dataset: str, seed: int, colour: bool) -> list[str]:
    """One photo (any pixels) and its mask; returns the native class name of each pixel."""
    table = TABLES[dataset]
    names = list(table)
    layout = class_layout(len(names), seed)
    rng = np.random.default_rng(seed)
    _write(image, rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8))
    if colour:
        colors = np.asarray([table[n][1] for n in names], dtype=np.uint8)
        _write(mask, colors[layout])
    else:
        ids = np.asarray([table[n][0] for n in names], dtype=np.uint8)
        _write(mask, ids[layout])
    return [names[i] for i in layout.ravel()]


def make_tree(root: Path, dataset: str, per_split: int = 2) -> dict[str, list[str]]:
    """A tree of ``dataset`` under ``root`` laid out as its release; returns, per mask file
    (relative to ``root``), the native class name of each pixel (row-major)."""
    truth: dict[str, list[str]] = {}

    def pair(image: str, mask: str, seed: int, colour: bool) -> None:
        truth[mask] = write_pair(root / image, root / mask, dataset, seed, colour)

    seed = 0
    if dataset == "uavid":
        for split in ("train", "val"):
            for i in range(per_split):
                base = f"uavid_{split}/seq{i + 1}"
                pair(f"{base}/Images/000000.png", f"{base}/Labels/000000.png", seed := seed + 1,
                     True)  # fmt: skip
    elif dataset in ("udd5", "udd6", "vdd"):
        for split in ("train", "val"):
            for i in range(per_split):
                stem = f"DJI_{split}_{i:04d}"
                pair(f"{split}/src/{stem}.JPG", f"{split}/gt/{stem}.png", seed := seed + 1, False)
    elif dataset == "aeroscapes":
        lists: dict[str, list[str]] = {"trn": [], "val": []}
        for split in lists:
            for i in range(per_split):
                stem = f"{len(truth) + 1:06d}_{i:03d}"
                lists[split].append(stem)
                pair(f"JPEGImages/{stem}.jpg", f"SegmentationClass/{stem}.png", seed := seed + 1,
                     False)  # fmt: skip
        (root / "ImageSets").mkdir(parents=True, exist_ok=True)
        for split, stems in lists.items():
            (root / "ImageSets" / f"{split}.txt").write_text("\n".join(stems) + "\n")
    elif dataset == "icg":
        for i in range(per_split * 2):
            labels = "training_set/gt/semantic/label_images"
            pair(f"training_set/images/{i:03d}.jpg", f"{labels}/{i:03d}.png", seed := seed + 1,
                 True)  # fmt: skip
        (root / "training_set" / "gt" / "semantic" / "class_dict.csv").write_text(ICG_CSV)
    else:
        raise ValueError(dataset)
    return truth
