"""Cameras on a flight grid over a synthetic world, and the frames they see.

The world is a ground plane (z = 0) with drawn objects; a pixel sees the ground point its ray
hits, so labels and colours come from one homography (ground -> image). Depth is the distance
along the optical axis to that point, shortened by the height of the object drawn there (the
ray meets height h at the fraction (z_cam - h) / z_cam of its way to the ground).
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
    IMAGE_SIZE,
    INTRINSICS,
    UNLABELED_ID,
)
from claravid.synth.world import WORLD_HALF_M, World

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


def scaled_intrinsics(size: tuple[int, int]) -> np.ndarray:
    """The ClaraVid intrinsics scaled from the native 4032×3024 to ``size`` = (width, height)."""
    k = INTRINSICS.astype(np.float64).copy()
    k[0] *= size[0] / IMAGE_SIZE[0]
    k[1] *= size[1] / IMAGE_SIZE[1]
    return k


def camera_to_world(position: np.ndarray, heading: float, pitch_deg: float) -> np.ndarray:
    """A camera-to-world pose (OpenCV axes: x right, y down, z forward; world z up).

    Args:
        position: camera centre (x, y, z) in metres.
        heading: direction of flight in the ground plane, radians from +x.
        pitch_deg: angle of the optical axis below the horizon (90 = straight down).
    """
    d = np.array([np.cos(heading), np.sin(heading), 0.0])
    p = np.deg2rad(pitch_deg)
    forward = np.cos(p) * d + np.array([0.0, 0.0, -np.sin(p)])
    right = np.cross(d, [0.0, 0.0, 1.0])  # from the heading, so a nadir camera is defined too
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, forward], 1)
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
    k = scaled_intrinsics(size)
    rot, centre = pose[:3, :3], pose[:3, 3]
    rt = rot.T
    ground_to_image = k @ np.column_stack([rt[:, 0], rt[:, 1], -rt @ centre])
    r = world.res
    origin = -WORLD_HALF_M + 0.5 * r
    raster_to_ground = np.array([[r, 0, origin], [0, r, origin], [0, 0, 1.0]])
    m = ground_to_image @ raster_to_ground
    # Rays: world z of K^-1 (u, v, 1) rotated; < 0 means the ray goes down to the ground.
    u = np.arange(width, dtype=np.float32)  # pixel centres sit at integer coordinates (cx = W/2)
    v = np.arange(height, dtype=np.float32)
    dz = (rot[2] @ np.linalg.inv(k)).astype(np.float32)  # ray z per unit of camera depth
    down = -(dz[0] * u[None, :] + dz[1] * v[:, None] + dz[2])
    ground = down > 1e-6
    sky = None if ground.all() else ~ground
    down[~ground] = 1.0

    def warp(layer: np.ndarray, flags: int, border: float | list[float]) -> np.ndarray:
        out = cv2.warpPerspective(
            layer, m, (width, height), flags=flags, borderMode=cv2.BORDER_CONSTANT,
            borderValue=border,
        )  # fmt: skip
        return np.asarray(out)

    packed = warp(world.packed, cv2.INTER_NEAREST, UNLABELED_ID * 65536.0).astype(np.int32)
    semantic, instance = (packed >> 16).astype(np.uint8), (packed & 0xFFFF).astype(np.uint16)
    lift = warp(world.height, cv2.INTER_NEAREST, 0.0)
    rgb = warp(world.color, cv2.INTER_LINEAR, _SKY.tolist())

    # Depth along the optical axis: to the ground, shortened to where the ray meets the object top.
    lift *= np.float32(-1.0 / centre[2])
    lift += 1.0
    depth = np.float32(centre[2]) / down
    depth *= np.clip(lift, 0.05, 1.0, out=lift)
    np.clip(depth, 0.01, DEPTH_MAX_M, out=depth)
    if sky is not None:
        semantic[sky], instance[sky], depth[sky], rgb[sky] = UNLABELED_ID, 0, DEPTH_MAX_M, _SKY
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
