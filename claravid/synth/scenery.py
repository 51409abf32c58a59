"""What a mission's world holds and where: ground, roads, buildings, vegetation, traffic, props.

:func:`build_world` places everything in metres with a generator seeded by (seed, mission),
drawing as it goes (later things are placed around earlier ones), then adds surface texture
and the cast shadows.
"""

from __future__ import annotations

import itertools
from typing import overload

import cv2
import numpy as np

from claravid.synth.world import (
    _CAR_COLOURS,
    _ROOF_COLOURS,
    _SHIFT,
    _TEXTURE,
    ID,
    PROFILES,
    WORLD_HALF_M,
    Colour,
    Profile,
    World,
    _along,
    _Canvas,
    _rect,
    _tangents,
    _wavy_road,
)


def _blob(rng: np.random.Generator, center: np.ndarray, radius: float) -> np.ndarray:
    """An irregular closed outline (lake, forest patch) around ``center``."""
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    r = radius * (
        1 + 0.25 * np.sin(3 * a + rng.uniform(0, 6)) + 0.15 * np.sin(5 * a + rng.uniform(0, 6))
    )
    return center + np.stack([np.cos(a), np.sin(a)], 1) * r[:, None]


class _Builder:
    """Places one mission's content in metres and draws it; one method per kind of thing."""

    def __init__(self, profile: Profile, rng: np.random.Generator, res: float) -> None:
        self.p, self.rng, self.cv = profile, rng, _Canvas(res)
        self.next_id = 1
        self.dynamic: list[int] = []
        self.roads: list[tuple[np.ndarray, float]] = []
        sun = rng.uniform(0, 2 * np.pi)
        self.sun = np.array([np.cos(sun), np.sin(sun)]) * rng.uniform(0.5, 0.9)

    def new_id(self, dynamic: bool = False) -> int:
        self.next_id += 1
        if dynamic:
            self.dynamic.append(self.next_id - 1)
        return self.next_id - 1

    def jitter(self, base: Colour, spread: float = 12.0) -> np.ndarray:
        return np.clip(np.asarray(base, float) + self.rng.normal(0, spread, 3), 0, 255)

    @overload
    def u(self, lo: float = ..., hi: float = ..., n: None = None) -> float: ...
    @overload
    def u(self, lo: float = ..., hi: float = ..., *, n: int) -> np.ndarray: ...
    @overload
    def u(self, lo: float, hi: float, n: int) -> np.ndarray: ...
    def u(
        self, lo: float = -WORLD_HALF_M, hi: float = WORLD_HALF_M, n: int | None = None
    ) -> float | np.ndarray:
        """A uniform draw in [lo, hi): a float, or ``n`` of them in an array."""
        return self.rng.uniform(lo, hi, n)

    # ---------------------------------------------------------------- ground
    def ground(self) -> None:
        cv, rng = self.cv, self.rng
        if self.p.paved_ground:
            cv.label[:] = ID["SideWalk"]
            cv.color[:] = (168, 163, 155)
        else:
            cv.color[:] = (98, 122, 62)
        if self.p.fields:
            for _ in range(40):
                pts = _rect(self.u(n=2), rng.uniform(50, 140, 2), rng.uniform(-0.3, 0.3))
                colour = self.jitter(
                    [(150, 140, 80), (110, 135, 60), (135, 110, 75)][rng.integers(3)], 8
                )
                cv.poly(pts, "Terrain", colour)
                # Crop rows: faint parallel lines across the field.
                d = pts[1] - pts[0]
                for t in np.arange(0.05, 1, 4.0 / max(float(np.linalg.norm(d)), 1.0)):
                    cv.line(
                        np.stack([pts[0] + t * d, pts[3] + t * d]), 0.6, "Terrain", colour * 0.9
                    )
        for _ in range(self.p.water):
            self.lake(np.array(self.u(-200, 200, 2)), rng.uniform(30, 70))

    def lake(self, center: np.ndarray, radius: float) -> None:
        pts = _blob(self.rng, center, radius)
        self.cv.poly(pts, "Water", self.jitter((42, 72, 92), 6))
        self.cv.occupy(pts)
        if "boats" in self.p.extras:
            for _ in range(int(radius / 8)):
                a, r = self.u(0, 2 * np.pi), self.u(0, 0.6 * radius)
                q = center + r * np.array([np.cos(a), np.sin(a)])
                dynamic = self.rng.random() < 0.5
                self.vehicle(q, self.u(0, np.pi), (7.0, 2.6), dynamic, on=("Water",))

    # ---------------------------------------------------------------- roads
    def road_network(self) -> None:
        p, rng = self.p, self.rng
        w = p.road_width
        if p.roads == "grid":
            for axis in (0, 1):
                start = self.u(0, p.block)
                for c in np.arange(-WORLD_HALF_M - start, WORLD_HALF_M + p.block, p.block):
                    c += rng.normal(0, 4)
                    t = np.array([-WORLD_HALF_M - 20, WORLD_HALF_M + 20])
                    pts = np.stack([t, [c, c]], 1) if axis == 0 else np.stack([[c, c], t], 1)
                    self.roads.append((pts, w))
        elif p.roads == "highway":
            a = self.u(-0.2, 0.2)
            self.roads.append((_wavy_road(rng, a, self.u(-30, 30), 15), 2.2 * w))
            self.roads.append(
                (_wavy_road(rng, a + np.pi / 2 + self.u(-0.3, 0.3), self.u(-60, 60), 20), w)
            )
            ramp = np.asarray(cv2.ellipse2Poly((0, 0), (60, 60), 0, 0, 270, 10), float)
            ramp += self.u(-40, 40, 2)
            self.roads.append((ramp, 0.6 * w))
        elif p.roads == "rural":
            for _ in range(3):
                self.roads.append((_wavy_road(rng, self.u(0, np.pi), self.u(-150, 150), 25), w))
        else:
            self.roads.append((_wavy_road(rng, self.u(0, np.pi), self.u(-60, 60), 40), w))
        water = self.cv.label == ID["Water"]
        for path, width in self.roads:
            if p.sidewalk:
                self.cv.line(path, width + 2 * p.sidewalk, "SideWalk", (182, 178, 170))
        for path, width in self.roads:
            self.cv.line(path, width, "Road", self.jitter((78, 78, 82), 4))
        # Where a road crosses water it is a bridge.
        bridge = water & (self.cv.label == ID["Road"])
        self.cv.label[bridge], self.cv.color[bridge] = ID["Bridge"], (150, 146, 138)
        for path, width in self.roads:
            self.lane_lines(path, width)
            thick = max(1, round((width + 2 * p.sidewalk + 2) / self.cv.res))
            cv2.polylines(self.cv.occupied, [self.cv.px(path)], False, 1, thick, cv2.LINE_8, _SHIFT)
        if "guard_rails" in p.extras:
            for path, width in self.roads[:1]:
                _, d = _tangents(path)
                n = np.stack([-d[:, 1], d[:, 0]], 1)
                n = np.concatenate([n, n[-1:]])
                for side in (-1, 0, 1):
                    self.cv.line(path + side * (width / 2 + 0.3 * side) * n if side else path, 0.5,
                                 "GuardRail", (190, 190, 185), 0.8)  # fmt: skip

    def lane_lines(self, path: np.ndarray, width: float) -> None:
        cum, _ = _tangents(path)
        lanes = max(1, int(width // 3.5))
        s = np.arange(0, cum[-1], 3.0)
        pts, d = _along(path, s)
        n = np.stack([-d[:, 1], d[:, 0]], 1)
        for k in range(1, lanes):
            off = (k / lanes - 0.5) * width
            q = pts + off * n
            centre = abs(off) < 0.1 * width
            colour = (215, 190, 70) if centre and lanes > 1 else (228, 228, 222)
            for i in range(0, len(q) - 1, 1 if centre else 2):
                self.cv.line(q[i : i + 2], 0.18, "RoadLine", colour)
        for side in (-1, 1):  # solid edge lines
            self.cv.line(pts + side * (width / 2 - 0.4) * n, 0.15, "RoadLine", (220, 220, 215))

    # ---------------------------------------------------------------- objects
    def vehicle(self, q, angle, size=(4.5, 1.9), dynamic=False, on=("Road", "RoadLine", "Bridge")):
        """A car, truck or boat centred on one of the ``on`` surfaces, overlapping none."""
        pts = _rect(q, size, angle)
        corners = np.round((np.vstack([pts, [q]]) + WORLD_HALF_M) / self.cv.res).astype(int)
        if corners.min() < 0 or corners.max() >= self.cv.label.shape[0]:
            return
        if self.cv.label[corners[-1, 1], corners[-1, 0]] not in [ID[n] for n in on]:
            return
        if np.any(self.cv.instance[corners[:, 1], corners[:, 0]]):
            return
        colour = self.jitter(_CAR_COLOURS[self.rng.integers(len(_CAR_COLOURS))], 6)
        inst = self.new_id(dynamic)
        self.cv.cast(pts, self.sun * 1.5)
        self.cv.poly(pts, "Vehicles", colour, 1.6, inst)
        # A dark windscreen band makes cars read as cars from above.
        front = np.asarray(q) + 0.18 * size[0] * np.array([np.cos(angle), np.sin(angle)])
        self.cv.poly(_rect(front, (0.22 * size[0], 0.85 * size[1]), angle), "Vehicles",
                     colour * 0.35 + 10, 1.6, inst)  # fmt: skip

    def traffic(self) -> None:
        rng = self.rng
        for path, width in self.roads:
            length = _tangents(path)[0][-1]
            lanes = max(1, int(width // 3.5))
            for k in range(lanes):
                off = ((k + 0.5) / lanes - 0.5) * width
                gap = 1000.0 / max(self.p.vehicles_per_km, 1e-3) * lanes
                s = np.cumsum(rng.exponential(gap, int(length / gap * 2) + 2) + 6)
                s = s[s < length]
                pts, d = _along(path, s)
                for q, t in zip(pts + off * np.stack([-d[:, 1], d[:, 0]], 1), d, strict=True):
                    if np.abs(q).max() > WORLD_HALF_M - 5:
                        continue
                    big = rng.random() < (0.3 if self.p.roads == "highway" else 0.08)
                    angle = np.arctan2(t[1], t[0]) + (np.pi if off < 0 else 0)
                    dynamic = rng.random() < self.p.dynamic_vehicles
                    self.vehicle(q, angle, (9.5, 2.5) if big else (4.5, 1.9), dynamic)

    def parking(self) -> None:
        for _ in range(self.p.parking):
            for _attempt in range(30):
                c, size = self.u(-150, 150, 2), self.rng.uniform([40, 30], [80, 50])
                lot = _rect(c, size, 0.0)
                if self.cv.free(lot, 1.0):
                    break
            else:
                continue
            self.cv.poly(lot, "Road", self.jitter((88, 88, 90), 3))
            self.cv.occupy(lot)
            x0, y0 = c - size / 2 + 3
            for row_y in np.arange(y0 + 2.5, y0 + size[1] - 6, 7.0):
                for col_x in np.arange(x0, x0 + size[0] - 6, 2.6):
                    self.cv.line(np.array([[col_x, row_y - 2.5], [col_x, row_y + 2.5]]), 0.15,
                                 "RoadLine", (225, 225, 220))  # fmt: skip
                    if self.rng.random() < 0.7:
                        self.vehicle((col_x + 1.3, row_y), np.pi / 2, (4.4, 1.8), dynamic=False)

    def building(self, pts: np.ndarray, height: float, colour: Colour) -> None:
        inst = self.new_id()
        self.cv.cast(pts, self.sun * height)
        self.cv.poly(pts, "Building", colour, height, inst)
        c = pts.mean(0)
        # Gable or flat roof detail: half the roof lighter (ridge), or rooftop units.
        half = np.stack([pts[0], pts[1], (pts[1] + pts[2]) / 2, (pts[0] + pts[3]) / 2])
        if self.rng.random() < 0.5 and not self.p.rooftop:
            self.cv.poly(half, "Building", np.clip(np.asarray(colour) * 1.25, 0, 255), height, inst)
        edge = pts[1] - pts[0]
        angle = np.arctan2(edge[1], edge[0])
        units = self.rng.integers(2, 7) if self.p.rooftop else self.rng.integers(0, 2)
        for _ in range(units):
            q = c + (self.rng.uniform(-0.3, 0.3, 2) @ np.stack([pts[1] - pts[0], pts[3] - pts[0]]))
            self.cv.poly(_rect(q, self.rng.uniform(1.5, 4, 2), angle), "Building",
                         self.jitter((200, 200, 205), 15), height + 1.5, inst)  # fmt: skip
        self.cv.occupy(pts)

    def buildings(self) -> None:
        p, rng = self.p, self.rng
        grid = p.roads == "grid"
        for _ in range(p.buildings * 12):
            if self.next_id > 60000 or p.buildings == 0:
                break
            lo, hi = p.building_size
            pts = _rect(self.u(n=2), rng.uniform(lo, hi, 2),
                        rng.normal(0, 0.05) if grid else rng.uniform(0, np.pi))  # fmt: skip
            if self.cv.free(pts, 1.0 if grid else 4.0):
                colour = self.jitter(_ROOF_COLOURS[rng.integers(len(_ROOF_COLOURS))], 10)
                self.building(pts, rng.uniform(*p.building_height), colour)
        if "mall" in p.extras:
            for _ in range(20):
                pts = _rect(self.u(-120, 120, 2), (70, 45), 0.0)
                if self.cv.free(pts, 2.0):
                    self.building(pts, 14.0, (205, 205, 200))
                    break

    def tree(self, center: np.ndarray, radius: float) -> None:
        rng = self.rng
        h = radius * rng.uniform(1.8, 3.0)
        self.cv.cast(
            np.asarray(center) + radius * np.array([[1, 0], [0, 1], [-1, 0], [0, -1]]), self.sun * h
        )
        base = self.jitter((52, 82, 36), 8)
        self.cv.disc(center, radius, "Vegetation", base, h)
        self.cv.disc(
            np.asarray(center) - self.sun * radius * 0.25,
            radius * 0.6,
            "Vegetation",
            base * 1.15,
            h,
        )

    def vegetation(self) -> None:
        rng = self.rng
        for _ in range(self.p.forest):
            c, r = self.u(-250, 250, 2), rng.uniform(40, 90)
            patch = _blob(rng, c, r)
            self.cv.poly(patch, "Vegetation", (44, 70, 32), 12.0)
            for _ in range(int(r * r / 40)):
                a, d = rng.uniform(0, 2 * np.pi), r * np.sqrt(rng.random()) * 0.9
                self.tree(c + d * np.array([np.cos(a), np.sin(a)]), rng.uniform(2.0, 4.0))
        for _ in range(self.p.trees):
            c, r = self.u(n=2), rng.uniform(1.5, 4.0)
            if self.cv.free(_rect(c, (2 * r, 2 * r), 0), 0.5):
                self.tree(c, r)

    def pedestrians(self) -> None:
        rng, p = self.rng, self.p
        walkable = (ID["SideWalk"], ID["Terrain"], ID["Bridge"])
        placed, tries = 0, 0
        while placed < p.pedestrians and tries < p.pedestrians * 20:
            tries += 1
            if self.roads and p.sidewalk and rng.random() < 0.7:
                path, width = self.roads[rng.integers(len(self.roads))]
                q, d = _along(path, rng.uniform(0, _tangents(path)[0][-1], 1))
                side = rng.choice([-1, 1]) * (width / 2 + rng.uniform(0.3, p.sidewalk - 0.3))
                q = q[0] + side * np.array([-d[0, 1], d[0, 0]])
            else:
                q = self.u(-200, 200, 2)
            i = np.round((q + WORLD_HALF_M) / self.cv.res).astype(int)
            if i.min() < 0 or i.max() >= self.cv.label.shape[0]:
                continue
            if self.cv.label[i[1], i[0]] not in walkable or self.cv.instance[i[1], i[0]]:
                continue
            # Crowds: some pedestrians come in small groups around the first one.
            for _ in range(rng.integers(1, 4)):
                g = q + rng.normal(0, 0.8, 2)
                self.cv.cast(g + np.array([[0.25, 0], [-0.25, 0]]), self.sun * 1.7)
                inst = self.new_id(rng.random() < p.dynamic_pedestrians)
                self.cv.disc(g, 0.3, "Pedestrian", self.jitter((120, 90, 80), 50), 1.7, inst)
                placed += 1

    # ---------------------------------------------------------------- props
    def props(self) -> None:
        rng, p, cv = self.rng, self.p, self.cv
        ex = p.extras
        if "poles" in ex or "traffic_signs" in ex:
            for path, width in self.roads:
                pts, d = _along(path, np.arange(10, _tangents(path)[0][-1], 30.0))
                n = np.stack([-d[:, 1], d[:, 0]], 1)
                for q in pts + (width / 2 + p.sidewalk * 0.7 + 0.5) * n:
                    if np.abs(q).max() < WORLD_HALF_M - 2:
                        cv.disc(q, 0.3, "Pole", (150, 150, 150), 8.0)
                        cv.cast(np.stack([q, q]), self.sun * 8.0)
                        if "traffic_signs" in ex and rng.random() < 0.3:
                            cv.disc(
                                q + rng.normal(0, 1.0, 2), 0.5, "TrafficSign", (200, 40, 40), 3.0
                            )
        if "power_lines" in ex:
            for _ in range(2):
                path = _wavy_road(rng, self.u(0, np.pi), self.u(-200, 200), 0)
                towers, _ = _along(path, np.arange(0, _tangents(path)[0][-1], 45.0))
                for a, b in itertools.pairwise(towers):
                    for off in (-1.5, 0.0, 1.5):
                        cv.line(np.stack([a, b]) + off, 0.12, "Wire", (40, 40, 40), 12.0)
                for q in towers:
                    cv.poly(_rect(q, (2.5, 2.5), 0.4), "Pole", (120, 120, 118), 15.0)
                    cv.cast(_rect(q, (1.0, 1.0), 0.4), self.sun * 15)
        if "fences" in ex:
            for _ in range(25):
                pts = _rect(self.u(-250, 250, 2), rng.uniform(15, 45, 2), rng.uniform(0, np.pi))
                if cv.free(pts, 0.0):
                    cv.line(np.vstack([pts, pts[:1]]), 0.25, "Fence", (95, 75, 55), 1.5)
        if "solar" in ex:
            for _ in range(3):
                c, angle = self.u(-200, 200, 2), rng.uniform(-0.2, 0.2)
                if not cv.free(_rect(c, (80, 60), angle), 2.0):
                    continue
                d, n = (
                    np.array([np.cos(angle), np.sin(angle)]),
                    np.array([-np.sin(angle), np.cos(angle)]),
                )
                for k in np.arange(-27, 28, 6.0):
                    cv.poly(_rect(c + k * n, (76, 3.5), angle), "GreenEnergy", (30, 38, 70), 1.5)
                    cv.line(np.stack([c + k * n - 38 * d, c + k * n + 38 * d]), 0.1, "GreenEnergy",
                            (120, 130, 160), 1.5)  # fmt: skip
                cv.occupy(_rect(c, (80, 60), angle))
        if "turbines" in ex:
            for _ in range(4):
                q = self.u(-250, 250, 2)
                cv.disc(q, 2.0, "GreenEnergy", (235, 235, 235), 80.0)
                a = rng.uniform(0, 2 * np.pi)
                for k in range(3):
                    b = a + k * 2 * np.pi / 3
                    cv.line(np.stack([q, q + 25 * np.array([np.cos(b), np.sin(b)])]), 1.2,
                            "GreenEnergy", (230, 230, 230), 80.0)  # fmt: skip
                cv.cast(np.stack([q, q]), self.sun * 60)
        if "tents" in ex:
            for _ in range(12):
                c = self.u(-220, 220, 2)
                for _ in range(rng.integers(2, 6)):
                    pts = _rect(
                        c + rng.normal(0, 6, 2), rng.uniform(2, 4, 2), rng.uniform(0, np.pi)
                    )
                    if cv.free(pts, 0.5):
                        colour = [(210, 110, 30), (40, 120, 60), (40, 70, 160), (200, 200, 60)][
                            rng.integers(4)
                        ]
                        cv.cast(pts, self.sun * 1.8)
                        cv.poly(pts, "Tent", self.jitter(colour, 10), 1.8)
                        cv.occupy(pts)
        if "containers" in ex or "construction" in ex or "gas_pump" in ex:
            kinds = [k for k in ("containers", "construction", "gas_pump") if k in ex]
            for kind in kinds:
                for _ in range(3 if kind != "gas_pump" else 1):
                    c = self.u(-180, 180, 2)
                    yard = _rect(c, (50, 35), 0.0)
                    if not cv.free(yard, 1.0):
                        continue
                    if kind == "construction":
                        cv.poly(yard, "Terrain", (150, 120, 85))
                        cv.line(np.vstack([yard, yard[:1]]), 0.25, "Fence", (95, 75, 55), 2.0)
                    elif kind == "gas_pump":
                        cv.poly(yard, "Road", (95, 95, 98))
                        cv.poly(_rect(c, (24, 12), 0.0), "Urban props", (225, 225, 225), 5.0)
                    for _ in range(14 if kind != "gas_pump" else 4):
                        q = c + rng.uniform([-22, -14], [22, 14])
                        if kind == "containers":
                            colour = [(170, 50, 40), (40, 90, 150), (60, 130, 70), (200, 140, 40)][
                                rng.integers(4)
                            ]
                            pts, cls, h = _rect(q, (12, 2.4), 0.0), "Urban props", 2.6
                        elif kind == "construction":
                            colour = (210, 150, 40)
                            pts, cls, h = (
                                _rect(q, rng.uniform(2, 6, 2), rng.uniform(0, 3)),
                                "Constr props",
                                2.0,
                            )
                        else:
                            colour = (200, 60, 50)
                            pts, cls, h = _rect(q, (1.2, 2.0), 0.0), "Urban props", 1.8
                        cv.cast(pts, self.sun * h)
                        cv.poly(pts, cls, self.jitter(colour, 10), h)
                    cv.occupy(yard)
        if "towers" in ex:
            for _ in range(3):
                q = self.u(-200, 200, 2)
                pts = _rect(q, (5, 5), rng.uniform(0, np.pi))
                if cv.free(pts, 1.0):
                    self.building(pts, 25.0, (140, 120, 100))


_SHADED = np.zeros(256, bool)
_SHADED[[ID[n] for n in ("Terrain", "Road", "RoadLine", "SideWalk", "Water", "Bridge")]] = True


def _noise(rng: np.random.Generator, n: int, res: float, cell_m: float) -> np.ndarray:
    """Smooth random field (zero mean, unit-ish std) with features about ``cell_m`` metres wide."""
    cells = max(2, int(2 * WORLD_HALF_M / cell_m))
    if cells >= n:
        return rng.standard_normal((n, n), dtype=np.float32)
    field = rng.standard_normal((cells, cells), dtype=np.float32)
    return cv2.resize(field, (n, n), interpolation=cv2.INTER_CUBIC)


def build_world(mission: str, seed: int, res: float) -> World:
    """Draw the world of one mission (an SDK key of ``PROFILES``) at ``res`` metres per pixel.

    The layout depends only on ``(seed, mission)``; texture noise also on ``res``.
    """
    index = list(PROFILES).index(mission)
    rng = np.random.default_rng([seed, index, 0])
    b = _Builder(PROFILES[mission], rng, res)
    b.ground()
    b.road_network()
    b.parking()
    b.props()
    b.buildings()
    b.vegetation()
    b.traffic()
    b.pedestrians()
    cv = b.cv
    tex = np.random.default_rng([seed, index, 1])
    n = cv.label.shape[0]
    noise = 0.55 * _noise(tex, n, res, 25.0) + 0.35 * _noise(tex, n, res, 2.5)
    noise += 0.45 * tex.standard_normal((n, n), dtype=np.float32)
    noise *= _TEXTURE[cv.label]
    noise += 1.0
    shade = _SHADED[cv.label] & (cv.shadow > 0)
    noise[shade] *= 0.55
    color = np.clip(cv.color * noise[..., None], 0, 255).astype(np.uint8)
    dynamic = np.zeros(b.next_id, bool)
    dynamic[b.dynamic] = True
    return World(res, cv.label, cv.instance, cv.height, color, dynamic)
