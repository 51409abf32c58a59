"""Cameras on a flight grid over a synthetic world, and the frames they see.

The world is a ground plane (z = 0) carrying upright prisms (buildings, trees, vehicles,
poles...) whose heights are multiples of :data:`~claravid.synth.world.HEIGHT_STEP`. A pixel
sees the first point where its ray, through the pixel's centre, enters the world: the ray is
tested at every multiple of the height step from the highest object (or the camera) down to the
ground, and the first height at which it lies inside a prism (a roof exactly, a wall within one
step) is where it stops. Its label, instance and colour are those of the world cell at that
point and its depth is that point's planar depth, so every pixel's label is what lies at the 3D
point its depth and pose give: frames of a pass agree through depth and poses.

Poses use the real data's OpenGL camera axes, and pixel centres sit at integer + 0.5, both from
:mod:`claravid.io.layout`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from claravid.io.layout import (
    CLASSES,
    DEPTH_MAX_M,
    DYNAMIC_MASK_DYNAMIC,
    DYNAMIC_MASK_STATIC,
    PIXEL_CENTRE,
    UNLABELED_ID,
    pixel_to_camera,
    scaled_intrinsics,
)
from claravid.synth.world import HEIGHT_STEP, WORLD_HALF_M, World

#: Flight height range (metres) and camera pitch below the horizon (degrees) per altitude key.
FLIGHT: dict[str, tuple[tuple[float, float], float]] = {
    "low": ((45.0, 55.0), 45.0),
    "mid": ((55.0, 65.0), 55.0),
    "high": ((65.0, 75.0), 90.0),
}
#: Half the side of the square the flight grid covers, in metres.
GRID_HALF_M: float = 80.0
_SKY = np.array([190, 200, 215], np.uint8)

_PALETTE = np.zeros((256, 3), np.uint8)
for _c in CLASSES:
    _PALETTE[_c.id] = _c.color


def camera_to_world(position: np.ndarray, heading: float, pitch_deg: float) -> np.ndarray:
    """A camera-to-world pose in OpenGL camera axes (x right, y up, looking along −z; world z up).

    Args:
        position: camera centre (x, y, z) in metres.
        heading: direction of flight in the ground plane, radians from +x.
        pitch_deg: angle of the optical axis below the horizon (90 = straight down).
    """
    d = np.array([np.cos(heading), np.sin(heading), 0.0])
    p = np.deg2rad(pitch_deg)
    forward = np.cos(p) * d + np.array([0.0, 0.0, -np.sin(p)])
    right = np.cross(d, [0.0, 0.0, 1.0])  # from the heading, so a nadir camera is defined too
    back = -forward
    up = np.cross(back, right)  # x × y = z: a right-handed camera frame
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, up, back], 1)
    pose[:3, 3] = position
    return pose


def flight_poses(
    n: int, altitude: str, direction: str, rng: np.random.Generator
) -> list[np.ndarray]:
    """``n`` consecutive poses of a boustrophedon flight over the grid square.

    Passes run along x (``h``) or y (``v``); the camera looks along the direction of flight.
    Pass count grows with ``n`` so that the poses spread over the whole square.
    """
    (h_lo, h_hi), pitch = FLIGHT[altitude]
    passes = max(1, round(np.sqrt(n / 4)))
    per_pass = -(-n // passes)
    along = np.linspace(-GRID_HALF_M, GRID_HALF_M, per_pass) if per_pass > 1 else np.zeros(1)
    across = np.linspace(-GRID_HALF_M, GRID_HALF_M, passes) if passes > 1 else np.zeros(1)
    height = rng.uniform(h_lo + 1, h_hi - 1)
    poses = []
    for i in range(n):
        k, j = divmod(i, per_pass)
        forward = k % 2 == 0
        a = along[j] if forward else along[::-1][j]
        height = float(np.clip(height + rng.normal(0, 0.4), h_lo, h_hi))
        jitter = rng.normal(0, 0.5, 2)
        if direction == "h":
            xy, heading = (a, across[k]), 0.0 if forward else np.pi
        else:
            xy, heading = (across[k], a), np.pi / 2 if forward else -np.pi / 2
        position = np.array([xy[0] + jitter[0], xy[1] + jitter[1], height])
        poses.append(camera_to_world(position, heading + rng.normal(0, 0.01), pitch))
    return poses


@dataclass
class Frame:
    """Every modality of one rendered frame, in the writers' input form."""

    rgb: np.ndarray  # uint8 H×W×3
    depth: np.ndarray  # float32 H×W metres
    semantic: np.ndarray  # uint8 H×W class ids
    instance: np.ndarray  # uint16 H×W
    seg_color: np.ndarray  # uint8 H×W×3
    dynamic_mask: np.ndarray  # uint8 H×W


def render(
    world: World, pose: np.ndarray, size: tuple[int, int], rng: np.random.Generator
) -> Frame:
    """Render what a camera with pose ``pose`` (camera-to-world) sees, at ``size`` = (w, h)."""
    width, height = size
    hit = _first_hits(world, pose, size)
    depth = np.clip(hit.depth, 0.01, DEPTH_MAX_M)
    border = UNLABELED_ID * 65536.0  # sky, and ground beyond the world: Unlabeled
    packed = cv2.remap(world.packed, hit.col, hit.row, interpolation=cv2.INTER_NEAREST,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=border)  # fmt: skip
    codes = packed.astype(np.int32)
    semantic, instance = (codes >> 16).astype(np.uint8), (codes & 0xFFFF).astype(np.uint16)
    rgb = cv2.remap(world.color, hit.col, hit.row, interpolation=cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=_SKY.tolist())  # fmt: skip
    # Walls (the ray came in through a prism's side) take the top's colour, darker.
    rgb[hit.wall] = (rgb[hit.wall] * 0.7).astype(np.uint8)
    # Light haze with distance and sensor noise, so far and flat areas are not perfectly clean
    # (saturating uint8 arithmetic in OpenCV: float images of 4032×3024×3 would cost seconds).
    haze = np.clip(depth * np.float32(1 / 1500), 0, 0.3)
    rgb = cv2.blendLinear(rgb, np.broadcast_to(_SKY, rgb.shape).copy(), 1 - haze, haze)
    grain = rng.integers(0, 5, (height, width), dtype=np.uint8)
    # OpenCV takes a scalar for the second operand; its stubs know arrays only.
    rgb = cv2.subtract(cv2.add(rgb, cv2.merge([grain, grain, grain])), (2, 2, 2, 0))  # type: ignore[call-overload]

    dynamic = world.dynamic[instance] if len(world.dynamic) else np.zeros_like(semantic, bool)
    mask = np.where(dynamic, DYNAMIC_MASK_DYNAMIC, DYNAMIC_MASK_STATIC).astype(np.uint8)
    return Frame(rgb, depth, semantic, instance, _PALETTE[semantic], mask)


@dataclass
class _Hits:
    """Where each pixel's ray first enters the world (H×W each)."""

    col: np.ndarray  # float32 world raster column / row there (cell centres at integers, as
    row: np.ndarray  #   cv2.remap samples); far outside the raster for the sky
    depth: np.ndarray  # float32 planar depth of that point; DEPTH_MAX_M for the sky
    wall: np.ndarray  # bool: the cell there is taller (the ray came in through a wall)


def _first_hits(world: World, pose: np.ndarray, size: tuple[int, int]) -> _Hits:
    """March every ray down the height levels; the first level inside a prism is its hit.

    At level z the ray is at ``centre + (centre_z − z) · g`` in the ground plane, ``g`` its
    horizontal travel per metre of descent; it is inside the world where the cell there is at
    least z tall. The image is marched in bands of rows, whose arrays stay in the CPU's cache.
    """
    width, height = size
    rot, centre = pose[:3, :3].astype(np.float64), pose[:3, 3].astype(np.float64)
    ray = rot @ pixel_to_camera(scaled_intrinsics(size))  # world ray per metre of planar depth
    u = np.arange(width) + PIXEL_CENTRE
    res = world.res
    origin = (
        np.float32((centre[0] + WORLD_HALF_M) / res - 0.5),
        np.float32((centre[1] + WORLD_HALF_M) / res - 0.5),
    )
    levels = world.levels
    top = max(0, min(int(levels.max()), int(np.floor((centre[2] - 1e-3) / HEIGHT_STEP))))
    out = _Hits(
        np.full(height * width, -1e6, np.float32),  # the sky: outside the world raster
        np.full(height * width, -1e6, np.float32),
        np.full(height * width, DEPTH_MAX_M, np.float32),
        np.zeros(height * width, bool),
    )
    band = max(1, _BAND_PIXELS // width)
    for r0 in range(0, height, band):
        v = np.arange(r0, min(height, r0 + band)) + PIXEL_CENTRE
        span = slice(r0 * width, r0 * width + len(v) * width)

        def plane(i: int, v: np.ndarray = v) -> np.ndarray:
            return (ray[i, 0] * u[None, :] + (ray[i, 1] * v + ray[i, 2])[:, None]).ravel()

        down = -plane(2)
        ground = down > 1e-6  # the others look at the sky
        down = down[ground]
        step_c = (plane(0)[ground] / (down * res)).astype(np.float32)
        step_r = (plane(1)[ground] / (down * res)).astype(np.float32)
        col, row, level, wall = _march(levels, top, centre[2], origin, step_c, step_r)
        out.col[span][ground], out.row[span][ground], out.wall[span][ground] = col, row, wall
        descent = np.float32(centre[2]) - level * np.float32(HEIGHT_STEP)
        out.depth[span][ground] = descent / down.astype(np.float32)
    return _Hits(*(a.reshape(height, width) for a in (out.col, out.row, out.depth, out.wall)))


#: Pixels per band of the march, so that its arrays stay in cache (and under remap's limit).
_BAND_PIXELS = 1 << 14


def _march(
    levels: np.ndarray,
    top: int,
    centre_z: float,
    origin: tuple[np.float32, np.float32],
    step_c: np.ndarray,
    step_r: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """Raster column, row, level and wall flag of the first hit of each ray of one band."""
    n = len(step_c)
    out_col, out_row = np.empty(n, np.float32), np.empty(n, np.float32)
    out_level, out_wall = np.zeros(n, np.float32), np.zeros(n, bool)
    alive = np.arange(n)
    col, row = np.empty(n, np.float32), np.empty(n, np.float32)
    for level in range(top, -1, -1):
        m = len(alive)
        c, r = col[:m], row[:m]
        descent = np.float32(centre_z - level * HEIGHT_STEP)
        np.multiply(step_c, descent, out=c)
        c += origin[0]
        np.multiply(step_r, descent, out=r)
        r += origin[1]
        cell = cv2.remap(levels, c.reshape(1, -1), r.reshape(1, -1),
                         interpolation=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=0).ravel()  # fmt: skip
        found = cell >= level  # level 0: the ground, every remaining ray stops there
        if level and not found.any():
            continue
        done = alive[found]
        out_col[done], out_row[done] = c[found], r[found]
        out_level[done], out_wall[done] = level, cell[found] > level
        keep = ~found
        alive, step_c, step_r = alive[keep], step_c[keep], step_r[keep]
        if len(alive) == 0:
            break
    return out_col, out_row, out_level, out_wall
