"""The real UAV datasets' own classes, and the decoding of their masks onto a palette.

Each real dataset publishes its classes as ids (index masks), colours (colour masks) or both.
:data:`NATIVE` holds those tables as the datasets publish them (docs/data.md lists them);
a palette's real side (``real:`` in its YAML, :mod:`claravid.data.palettes`) maps each native
class, many-to-one, to one of the palette's classes or to ignore, and :class:`RealMap` decodes
a mask through that map: an exact id or colour match, anything else ignored and counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

IGNORE_ID = 255


@dataclass(frozen=True)
class NativeClass:
    """One class of a real dataset: its name, its id in index masks, its colour in colour masks
    (None where the dataset does not publish that encoding)."""

    name: str
    id: int | None
    color: tuple[int, int, int] | None


@dataclass(frozen=True)
class NativeTable:
    """A real dataset's published classes."""

    dataset: str
    title: str
    classes: tuple[NativeClass, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.classes)

    def get(self, name: str) -> NativeClass | None:
        return next((c for c in self.classes if c.name == name), None)


def _ids(names: str) -> tuple[NativeClass, ...]:
    return tuple(NativeClass(n, i, None) for i, n in enumerate(names.split(",")))


def _table(dataset: str, title: str, rows: list[tuple[str, int | None, str | None]]) -> NativeTable:
    def color(text: str | None) -> tuple[int, int, int] | None:
        if text is None:
            return None
        r, g, b = (int(v) for v in text.split())
        return (r, g, b)

    return NativeTable(dataset, title, tuple(NativeClass(n, i, color(c)) for n, i, c in rows))


#: The real datasets' own classes, keyed by the name ``--dataset`` and the palettes use.
NATIVE: dict[str, NativeTable] = {
    t.dataset: t
    for t in (
        # UAVid's labels are colour-coded; the ids are its train ids.
        _table("uavid", "UAVid", [
            ("Clutter", 0, "0 0 0"), ("Building", 1, "128 0 0"), ("Road", 2, "128 64 128"),
            ("Static car", 3, "192 0 192"), ("Tree", 4, "0 128 0"),
            ("Low vegetation", 5, "128 128 0"), ("Human", 6, "64 64 0"),
            ("Moving car", 7, "64 0 128"),
        ]),
        _table("udd5", "UDD5", [
            ("Vegetation", 0, "107 142 35"), ("Building", 1, "102 102 156"),
            ("Road", 2, "128 64 128"), ("Vehicle", 3, "0 0 142"), ("Other", 4, "0 0 0"),
        ]),
        _table("udd6", "UDD6", [
            ("Other", 0, "0 0 0"), ("Facade", 1, "102 102 156"), ("Road", 2, "128 64 128"),
            ("Vegetation", 3, "107 142 35"), ("Vehicle", 4, "0 0 142"), ("Roof", 5, "70 70 70"),
        ]),
        NativeTable("vdd", "VDD", _ids("other,wall,road,vegetation,vehicle,roof,water")),
        NativeTable("aeroscapes", "AeroScapes", _ids(
            "background,person,bike,car,drone,boat,animal,obstacle,construction,vegetation,"
            "road,sky"
        )),
        # The Semantic Drone Dataset's class_dict.csv: colour masks, no ids.
        _table("icg", "ICG (Semantic Drone Dataset)", [
            ("unlabeled", None, "0 0 0"), ("paved-area", None, "128 64 128"),
            ("dirt", None, "130 76 0"), ("grass", None, "0 102 0"),
            ("gravel", None, "112 103 87"), ("water", None, "28 42 168"),
            ("rocks", None, "48 41 30"), ("pool", None, "0 50 89"),
            ("vegetation", None, "107 142 35"), ("roof", None, "70 70 70"),
            ("wall", None, "102 102 156"), ("window", None, "254 228 12"),
            ("door", None, "254 148 12"), ("fence", None, "190 153 153"),
            ("fence-pole", None, "153 153 153"), ("person", None, "255 22 96"),
            ("dog", None, "102 51 0"), ("car", None, "9 143 150"),
            ("bicycle", None, "119 11 32"), ("tree", None, "51 51 0"),
            ("bald-tree", None, "190 250 190"), ("ar-marker", None, "112 150 146"),
            ("obstacle", None, "2 135 115"), ("conflicting", None, "255 0 0"),
        ]),
    )
}  # fmt: skip


def color_indices(rgb: np.ndarray, table: np.ndarray, missing: int) -> np.ndarray:
    """Index in ``table`` (N×3 RGB, distinct colours) of each pixel's colour, exact match.

    Returns uint8 H×W indices; colours not in the table get ``missing``.
    """

    def pack(c: np.ndarray) -> np.ndarray:
        c = np.asarray(c, dtype=np.uint32)
        return (c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]

    packed, keys = pack(rgb), pack(table)
    order = np.argsort(keys)
    slot = np.searchsorted(keys[order], packed).clip(0, len(keys) - 1)
    found = keys[order][slot] == packed
    return np.where(found, order[slot], missing).astype(np.uint8)


@dataclass(frozen=True)
class RealMap:
    """A real dataset's classes mapped onto a palette: decodes its masks to train ids.

    Attributes:
        dataset: the real dataset (a key of :data:`NATIVE`).
        targets: native class name -> palette train id (255: ignore), every native class.
    """

    dataset: str
    targets: dict[str, int]

    @property
    def table(self) -> NativeTable:
        return NATIVE[self.dataset]

    def _id_lut(self) -> tuple[np.ndarray, np.ndarray]:
        """uint8[256] native id -> train id, and bool[256] whether the id is a native class."""
        lut = np.full(256, IGNORE_ID, dtype=np.uint8)
        known = np.zeros(256, dtype=bool)
        known[IGNORE_ID] = True  # 255 in an index mask is ignore, not an unknown value
        for cls in self.table.classes:
            if cls.id is not None:
                lut[cls.id], known[cls.id] = self.targets[cls.name], True
        return lut, known

    def _colors(self) -> tuple[np.ndarray, np.ndarray]:
        """N×3 native colours and uint8[256] colour index -> train id (255 stays 255)."""
        rows = [c for c in self.table.classes if c.color is not None]
        colors = np.asarray([c.color for c in rows], dtype=np.uint8).reshape(-1, 3)
        lut = np.full(256, IGNORE_ID, dtype=np.uint8)
        lut[: len(rows)] = [self.targets[c.name] for c in rows]
        return colors, lut

    def decode(self, mask: np.ndarray) -> tuple[np.ndarray, int]:
        """Native ids (H×W uint8/uint16) or colours (H×W×3 RGB) -> (uint8 train ids, unknown
        pixels): values the dataset does not define become 255 and are counted."""
        if mask.ndim == 3:
            colors, lut = self._colors()
            if not len(colors):  # the dataset publishes ids only: no colour is known
                return np.full(mask.shape[:2], IGNORE_ID, np.uint8), mask.shape[0] * mask.shape[1]
            index = color_indices(mask, colors, missing=IGNORE_ID)
            return cv2.LUT(index, lut), int(np.count_nonzero(index == IGNORE_ID))
        lut, known = self._id_lut()
        if mask.dtype == np.uint8:  # two table lookups (~6x np.where on a 4000×3000 mask)
            unknown = cv2.LUT(mask, (~known).astype(np.uint8))
            return cv2.LUT(mask, lut), int(cv2.countNonZero(unknown))
        clipped = np.minimum(mask, 255).astype(np.uint8)  # uint16 values >= 256 are unknown
        is_known = known[clipped] & (mask <= 255)
        ids = np.where(is_known, cv2.LUT(clipped, lut), IGNORE_ID).astype(np.uint8)
        return ids, int(mask.size - np.count_nonzero(is_known))

    def unknown_share(self, masks: list[np.ndarray]) -> float:
        """The share of pixels of ``masks`` (read_label_image's arrays) this dataset does not
        define."""
        total = unknown = 0
        for mask in masks:
            ids, count = self.decode(mask)
            total, unknown = total + ids.size, unknown + count
        return unknown / max(total, 1)
