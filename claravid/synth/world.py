"""A procedurally drawn top-down world for one mission: label, instance, height and colour rasters.

Everything is placed in metres with a seeded generator first, then drawn into rasters at a
ground resolution chosen by the caller, so a world is the same scene at every resolution
(only its sharpness changes). Missions differ by a :class:`Profile` of densities: sparse
rural fields and forests on one end, dense towers with cars and crowds on the other.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TypeAlias

import cv2
import numpy as np
from numpy.typing import ArrayLike

from claravid.io.layout import CLASS_BY_NAME

#: A colour as RGB values in 0..255 (a tuple or an array).
Colour: TypeAlias = Sequence[float] | np.ndarray

#: Half the side of every world square, in metres (the flight grid stays well inside it).
WORLD_HALF_M: float = 300.0
#: Object heights are whole multiples of this (metres): the renderer tests every ray at each
#: multiple, so flat tops are hit exactly where they are.
HEIGHT_STEP: float = 0.5
_SHIFT = 4  # cv2 drawing with 4 fractional bits: sub-pixel placement at coarse resolutions
_ONE = 1 << _SHIFT

ID = {name: c.id for name, c in CLASS_BY_NAME.items()}


@dataclass(frozen=True)
class Profile:
    """How much of everything a mission holds (counts are per world, sizes in metres)."""

    roads: str  # "grid" (urban blocks), "rural" (a few long roads), "highway", "path"
    block: float = 90.0  # grid road spacing
    road_width: float = 7.0
    sidewalk: float = 0.0
    fields: bool = False  # crop-field patchwork as ground
    paved_ground: bool = False  # plazas (SideWalk) instead of lawns between buildings
    buildings: int = 0
    building_size: tuple[float, float] = (8.0, 20.0)
    building_height: tuple[float, float] = (4.0, 10.0)
    rooftop: bool = False  # rooftop equipment on buildings
    trees: int = 0
    forest: int = 0  # clustered forest patches
    water: int = 0
    vehicles_per_km: float = 20.0
    dynamic_vehicles: float = 0.4
    parking: int = 0
    pedestrians: int = 0
    dynamic_pedestrians: float = 0.5
    extras: tuple[str, ...] = ()


PROFILES: dict[str, Profile] = {
    "rural_1": Profile(
        "rural", road_width=6.0, fields=True, buildings=6, building_size=(15, 40),
        building_height=(5, 12), trees=60, water=1, vehicles_per_km=6, parking=0,
        pedestrians=4, extras=("power_lines",),
    ),
    "rural_2": Profile(
        "rural", road_width=6.5, fields=True, buildings=22, building_size=(9, 30),
        building_height=(4, 10), trees=120, water=1, vehicles_per_km=10, parking=1,
        pedestrians=10, extras=("fences",),
    ),
    "urban_1": Profile(
        "grid", block=75, road_width=8, sidewalk=2.5, buildings=220, building_size=(10, 22),
        building_height=(6, 18), trees=260, vehicles_per_km=45, parking=2, pedestrians=120,
        extras=("gas_pump", "poles", "fences"),
    ),
    "highway_1": Profile(
        "highway", road_width=10, fields=True, buildings=10, building_size=(12, 35),
        building_height=(5, 12), trees=90, water=2, vehicles_per_km=30, dynamic_vehicles=0.8,
        pedestrians=6, extras=("solar", "turbines", "guard_rails"),
    ),
    "highway_2": Profile(
        "highway", road_width=9, buildings=25, building_size=(10, 30), building_height=(5, 14),
        trees=110, water=1, vehicles_per_km=35, dynamic_vehicles=0.7, parking=1,
        pedestrians=30, extras=("boats", "tents", "containers", "guard_rails", "poles"),
    ),
    "urban_2": Profile(
        "grid", block=65, road_width=7, sidewalk=2.5, buildings=260, building_size=(9, 18),
        building_height=(5, 15), trees=220, vehicles_per_km=40, pedestrians=350,
        extras=("construction", "fences", "poles"),
    ),
    "nature_1": Profile(
        "path", road_width=4, buildings=3, building_size=(6, 10), building_height=(3, 6),
        trees=150, forest=9, water=3, vehicles_per_km=4, dynamic_vehicles=0.3,
        pedestrians=12, extras=("tents", "towers"),
    ),
    "urban_high_1": Profile(
        "grid", block=55, road_width=10, sidewalk=3.5, paved_ground=True, buildings=700,
        building_size=(9, 22), building_height=(18, 40), rooftop=True, trees=160,
        vehicles_per_km=70, dynamic_vehicles=0.5, parking=2, pedestrians=900,
        extras=("mall", "poles", "traffic_signs"),
    ),
}  # fmt: skip

# Realistic surface colours (RGB), not the label palette.
_CAR_COLOURS = np.array(
    [[235, 235, 235], [25, 25, 28], [150, 150, 155], [160, 20, 25], [30, 60, 140], [200, 200, 190],
     [60, 70, 60], [210, 160, 30], [90, 90, 100], [110, 30, 30]], dtype=np.float64,
)  # fmt: skip
_ROOF_COLOURS = np.array(
    [[150, 70, 55], [95, 95, 100], [170, 165, 155], [120, 85, 60], [60, 62, 68], [190, 185, 175],
     [135, 110, 95]], dtype=np.float64,
)  # fmt: skip
#: Texture amplitude per class: how strongly the world noise modulates each surface.
_TEXTURE = np.full(256, 0.10, dtype=np.float32)
for _name, _amp in {"Water": 0.04, "Road": 0.09, "Terrain": 0.16, "Vegetation": 0.22,
                    "SideWalk": 0.10, "Building": 0.06, "Vehicles": 0.02}.items():  # fmt: skip
    _TEXTURE[ID[_name]] = _amp


@dataclass
class World:
    """Top-down rasters of one mission; pixel (row r, col c) is at x = x0 + (c + ½)·res, y likewise.

    Attributes:
        res: metres per raster pixel.
        label: uint8 class ids. instance: uint16 ids (0 = none). height: float32 metres above
        ground, a multiple of :data:`HEIGHT_STEP` (objects are upright prisms). color: uint8 RGB
        of the top surfaces. dynamic: bool lookup, ``dynamic[instance]`` is True for
        moving vehicles and pedestrians.
    """

    res: float
    label: np.ndarray
    instance: np.ndarray
    height: np.ndarray
    color: np.ndarray
    dynamic: np.ndarray

    @cached_property
    def levels(self) -> np.ndarray:
        """Heights in :data:`HEIGHT_STEP` units, uint8 (the renderer's occupancy test)."""
        return np.clip(np.rint(self.height / HEIGHT_STEP), 0, 255).astype(np.uint8)

    @cached_property
    def packed(self) -> np.ndarray:
        """Class·65536 + instance in float32 (exact below 2^24): one warp keeps them paired."""
        return self.label.astype(np.float32) * 65536 + self.instance


class _Canvas:
    """Draws shapes given in metres into every raster at once, keeping them consistent."""

    def __init__(self, res: float) -> None:
        self.res = res
        n = int(np.ceil(2 * WORLD_HALF_M / res))
        self.label = np.full((n, n), ID["Terrain"], np.uint8)
        self.instance = np.zeros((n, n), np.uint16)
        self.height = np.zeros((n, n), np.float32)
        self.color = np.zeros((n, n, 3), np.uint8)
        self.shadow = np.zeros((n, n), np.uint8)
        self.occupied = np.zeros((n, n), np.uint8)

    def px(self, pts: ArrayLike) -> np.ndarray:
        """Metres -> fixed-point pixel coordinates for cv2 (``shift=_SHIFT``)."""
        return np.round((np.asarray(pts, float) + WORLD_HALF_M) / self.res * _ONE).astype(np.int32)

    def _layers(
        self, cls: str, color: Colour, height: float, inst: int
    ) -> tuple[tuple[np.ndarray, float | tuple[float, ...]], ...]:
        return (
            (self.label, ID[cls]),
            (self.instance, inst),
            (self.height, HEIGHT_STEP * round(height / HEIGHT_STEP)),
            (self.color, tuple(float(c) for c in color)),
        )

    def poly(
        self, pts: ArrayLike, cls: str, color: Colour, height: float = 0.0, inst: int = 0
    ) -> None:
        p = [self.px(pts)]
        for layer, value in self._layers(cls, color, height, inst):
            cv2.fillPoly(layer, p, value, cv2.LINE_8, _SHIFT)

    def line(
        self,
        pts: ArrayLike,
        width: float,
        cls: str,
        color: Colour,
        height: float = 0.0,
        inst: int = 0,
    ) -> None:
        t = max(1, round(width / self.res))
        p = [self.px(pts)]
        for layer, value in self._layers(cls, color, height, inst):
            cv2.polylines(layer, p, False, value, t, cv2.LINE_8, _SHIFT)

    def disc(
        self,
        center: ArrayLike,
        radius: float,
        cls: str,
        color: Colour,
        height: float = 0.0,
        inst: int = 0,
    ) -> None:
        c = tuple(int(v) for v in self.px(center))
        r = round(radius / self.res * _ONE)
        for layer, value in self._layers(cls, color, height, inst):
            cv2.circle(layer, c, r, value, -1, cv2.LINE_8, _SHIFT)

    def cast(self, pts: np.ndarray, offset: ArrayLike) -> None:
        """Mark the shadow of a prism with base ``pts`` cast along ``offset`` (metres)."""
        both = np.concatenate([pts, pts + offset])
        cv2.fillConvexPoly(self.shadow, self.px(cv2.convexHull(both.astype(np.float32))[:, 0]),
                           1, cv2.LINE_8, _SHIFT)  # fmt: skip

    def free(self, pts: np.ndarray, margin: float) -> bool:
        """Whether a polygon, grown by ``margin`` metres, touches nothing already placed."""
        lo = np.floor((pts.min(0) - margin + WORLD_HALF_M) / self.res).astype(int)
        hi = np.ceil((pts.max(0) + margin + WORLD_HALF_M) / self.res).astype(int) + 1
        n = self.label.shape[0]
        if lo.min() < 0 or hi.max() > n:
            return False
        window = self.occupied[lo[1] : hi[1], lo[0] : hi[0]]
        stamp = np.zeros_like(window)
        local = np.round((pts + WORLD_HALF_M - lo * self.res) / self.res * _ONE).astype(np.int32)
        cv2.fillPoly(stamp, [local], 1, cv2.LINE_8, _SHIFT)
        grow = max(1, round(margin / self.res))
        grown = cv2.dilate(stamp, np.ones((2 * grow + 1, 2 * grow + 1), np.uint8))
        return not np.any(np.logical_and(window, grown))

    def occupy(self, pts: ArrayLike) -> None:
        cv2.fillPoly(self.occupied, [self.px(pts)], 1, cv2.LINE_8, _SHIFT)


def _rect(center: ArrayLike, size: ArrayLike, angle: float) -> np.ndarray:
    """Corners (4×2, metres) of a rectangle centred at ``center`` (x, y) of ``size`` (length,
    width), long side along ``angle``."""
    c, s = np.cos(angle), np.sin(angle)
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * (np.asarray(size, float) / 2)
    return half @ np.array([[c, s], [-s, c]]) + np.asarray(center, float)


def _tangents(path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative arc length at each vertex and the unit direction of each segment."""
    seg = np.diff(path, axis=0)
    length = np.linalg.norm(seg, axis=1)
    return np.concatenate([[0.0], np.cumsum(length)]), seg / np.maximum(length, 1e-9)[:, None]


def _along(path: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points and unit tangents at arc lengths ``s`` along a polyline."""
    cum, direction = _tangents(path)
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(direction) - 1)
    return path[i] + direction[i] * (s - cum[i])[:, None], direction[i]


def _wavy_road(rng: np.random.Generator, angle: float, offset: float, wiggle: float) -> np.ndarray:
    """A long gently curving road across the whole world."""
    t = np.linspace(-1.3 * WORLD_HALF_M, 1.3 * WORLD_HALF_M, 60)
    bend = wiggle * np.sin(t / rng.uniform(80, 200) + rng.uniform(0, 2 * np.pi))
    d, n = np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])
    return t[:, None] * d + (offset + bend)[:, None] * n
