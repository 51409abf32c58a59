"""The ClaraVid dataset on disk: every fact of its layout, label set and cameras, in one place.

``<root>/<mission>/<modality>/<altitude>_<direction>/<stem>.<ext>``, for example
``003_urban_1/left_rgb/45deg_low_h/000123.jpg``. The keys (``urban_1``, ``low``, ``h``,
``rgb``...) are those of the official ClaraVid SDK, so code written for it reads the same.

Cameras (the generator, the pose reader and the cross-view measure all go through here):

- a pose is a camera-to-world 4×4 rigid transform whose camera axes are OpenGL's: x right,
  y up, and the camera looks along −z (world z up). A point in front of the camera has a
  negative camera z; its *depth* is the planar depth ``d = −z_c`` along the optical axis, which
  is what the depth PNGs hold (not the distance along the ray);
- pixel (row i, column j) of an image indexed from 0 covers ``[j, j+1) × [i, i+1)`` in pixel
  coordinates (u, v); its centre is ``(j + 0.5, i + 0.5)``. The intrinsics' principal point
  ``(2016, 1512)`` is then the centre of the 4032×3024 frame;
- projection: ``u = fx·x_c/d + cx`` and ``v = −fy·y_c/d + cy`` (y up, so v grows downwards);
  back-projection of pixel centre (u, v) with depth d: ``x_c = (u − cx)·d/fx``,
  ``y_c = −(v − cy)·d/fy``, ``z_c = −d``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: SDK mission key -> mission folder, in the SDK's (and the dataset's) order.
MISSIONS: dict[str, str] = {
    "rural_1": "001_rural_1",
    "rural_2": "002_rural_2",
    "urban_1": "003_urban_1",
    "highway_1": "004_highway_1",
    "highway_2": "005_highway_2",
    "urban_2": "006_urban_2",
    "nature_1": "007_nature_1",
    "urban_high_1": "008_urban_dense_1",
}
#: Older SDK releases call the last mission ``urban_high``; accepted as a synonym.
MISSION_ALIASES: dict[str, str] = {"urban_high": "urban_high_1"}

#: Altitude key -> folder prefix. Flight heights: low 45-55 m, mid 55-65 m, high 65-75 m.
ALTITUDES: dict[str, str] = {"low": "45deg_low", "mid": "55deg_mid", "high": "90deg_high"}

#: Grid direction key -> folder suffix (horizontal / vertical passes of a regular grid).
DIRECTIONS: dict[str, str] = {"h": "h", "v": "v"}


@dataclass(frozen=True)
class Modality:
    """One field of a frame: its SDK key, folder and file extension (None: no files)."""

    key: str
    folder: str | None
    ext: str | None

    def folder_in(self, mission_dir: Path) -> Path:
        """This modality's folder in a mission folder (ValueError for one without files)."""
        if self.folder is None:
            raise ValueError(f"the {self.key!r} field has no files, so no folder")
        return mission_dir / self.folder


#: SDK field key -> modality, in the SDK's default field order.
MODALITIES: dict[str, Modality] = {
    m.key: m
    for m in (
        Modality("rgb", "left_rgb", "jpg"),
        Modality("depth", "depth", "png"),
        Modality("seg_color", "semantic_colormap", "png"),
        Modality("pan_seg", "panoptic_seg", "png"),
        Modality("dynamic_mask", "dynamic_mask", "png"),
        Modality("extrinsics", "extrinsics", "json"),
        Modality("intrinsics", None, None),
    )
}

#: Native frame size (width, height) of every image modality.
IMAGE_SIZE: tuple[int, int] = (4032, 3024)

#: Pinhole intrinsics of the left camera at native size (HFoV 75 degrees).
FOCAL_PX: float = 2627.3023516478706
INTRINSICS: np.ndarray = np.array(
    [[FOCAL_PX, 0.0, 2016.0], [0.0, FOCAL_PX, 1512.0], [0.0, 0.0, 1.0]], dtype=np.float32
)
INTRINSICS.setflags(write=False)

#: Depth PNGs store metres as a 24-bit integer over three channels (CARLA's encoding).
DEPTH_MAX_M: float = 1000.0
DEPTH_SCALE: int = 256**3 - 1

#: Dynamic mask values.
DYNAMIC_MASK_STATIC: int = 255
DYNAMIC_MASK_DYNAMIC: int = 0

#: The label id for pixels without a class.
UNLABELED_ID: int = 255


@dataclass(frozen=True)
class SemanticClass:
    """A ClaraVid semantic class as stored in the R channel of ``panoptic_seg``."""

    id: int
    name: str
    color: tuple[int, int, int]
    has_instances: bool = False


#: The 19 classes plus Unlabeled; ids 11, 12, 20 and 21 are unused.
CLASSES: tuple[SemanticClass, ...] = (
    SemanticClass(0, "Building", (70, 70, 70), has_instances=True),
    SemanticClass(1, "Fence", (100, 40, 40)),
    SemanticClass(2, "Wire", (55, 90, 80)),
    SemanticClass(3, "Pedestrian", (220, 20, 60), has_instances=True),
    SemanticClass(4, "Pole", (153, 153, 153)),
    SemanticClass(5, "RoadLine", (157, 234, 50)),
    SemanticClass(6, "Road", (128, 64, 128)),
    SemanticClass(7, "SideWalk", (244, 35, 232)),
    SemanticClass(8, "Vegetation", (107, 142, 35)),
    SemanticClass(9, "Vehicles", (0, 0, 142), has_instances=True),
    SemanticClass(10, "TrafficSign", (220, 220, 0)),
    SemanticClass(13, "GreenEnergy", (230, 150, 140)),
    SemanticClass(14, "GuardRail", (180, 165, 180)),
    SemanticClass(15, "Urban props", (110, 190, 160)),
    SemanticClass(16, "Water", (45, 60, 150)),
    SemanticClass(17, "Terrain", (145, 170, 100)),
    SemanticClass(18, "Tent", (0, 60, 100)),
    SemanticClass(19, "Constr props", (170, 120, 50)),
    SemanticClass(22, "Bridge", (150, 100, 100)),
    SemanticClass(UNLABELED_ID, "Unlabeled", (0, 0, 0)),
)
CLASS_BY_NAME: dict[str, SemanticClass] = {c.name: c for c in CLASSES}
CLASS_BY_ID: dict[int, SemanticClass] = {c.id: c for c in CLASSES}


def canonical_mission(key: str) -> str:
    """Return the SDK key of a mission given its key, an alias or its folder name.

    Raises:
        ValueError: the name is not a ClaraVid mission; the message lists the valid keys.
    """
    if key in MISSIONS:
        return key
    if key in MISSION_ALIASES:
        return MISSION_ALIASES[key]
    by_folder = {folder: k for k, folder in MISSIONS.items()}
    if key in by_folder:
        return by_folder[key]
    raise ValueError(f"unknown ClaraVid mission {key!r}; valid missions: {', '.join(MISSIONS)}")


def frame_file(mission_dir: Path, viewpoint: str, stem: str, field: str) -> Path:
    """The file of one field of a frame: ``<mission_dir>/<modality>/<viewpoint>/<stem>.<ext>``."""
    modality = MODALITIES[field]
    return modality.folder_in(mission_dir) / viewpoint / f"{stem}.{modality.ext}"


def viewpoint_folder(altitude: str, direction: str) -> str:
    """Folder name of a viewpoint, e.g. ``viewpoint_folder('low', 'h') == '45deg_low_h'``."""
    return f"{ALTITUDES[altitude]}_{DIRECTIONS[direction]}"


# --------------------------------------------------------------------------------------------
# Cameras: axes, pixel grid, projection.

#: Offset of a pixel's centre from its integer index: pixel j spans [j, j+1), centre j + 0.5.
PIXEL_CENTRE: float = 0.5

#: Camera axes of the poses: OpenGL's (x right, y up, looking along −z). Multiplying camera
#: coordinates by this matrix gives OpenCV's (x right, y down, looking along +z), and back.
OPENGL_TO_OPENCV: np.ndarray = np.diag([1.0, -1.0, -1.0])
OPENGL_TO_OPENCV.setflags(write=False)

#: How far from a rigid transform a pose may be (rounding in the files), per matrix entry.
RIGID_TOLERANCE: float = 1e-4


def scaled_intrinsics(size: tuple[int, int]) -> np.ndarray:
    """The intrinsics (float64 3×3) of a frame resized from 4032×3024 to ``size`` = (w, h).

    Pixel coordinates scale with the image (the centre convention above is kept), so the
    principal point stays at the frame's centre.
    """
    k = INTRINSICS.astype(np.float64)
    k[0] *= size[0] / IMAGE_SIZE[0]
    k[1] *= size[1] / IMAGE_SIZE[1]
    return k


def pixel_to_camera(intrinsics: np.ndarray) -> np.ndarray:
    """A (float64 3×3) with ``camera point = d · A · (u, v, 1)`` for pixel (u, v) at depth d."""
    return OPENGL_TO_OPENCV @ np.linalg.inv(np.asarray(intrinsics, dtype=np.float64))


def world_to_image(c2w: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """P (float64 3×4) with ``P · (X, 1) = d · (u, v, 1)``: the pixel and depth of world X.

    ``d`` is the planar depth (positive in front of the camera); (u, v) are pixel coordinates
    with pixel centres at integer + 0.5.
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    w2c = np.linalg.inv(c2w)[:3]
    return np.asarray(intrinsics, dtype=np.float64) @ OPENGL_TO_OPENCV @ w2c


def camera_points(depth: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """The camera-frame point (float64 H×W×3) of every pixel centre, from its planar depth."""
    depth = np.asarray(depth, dtype=np.float64)
    height, width = depth.shape
    u = np.arange(width) + PIXEL_CENTRE
    v = np.arange(height) + PIXEL_CENTRE
    uv1 = np.stack([*np.meshgrid(u, v), np.ones_like(depth)], axis=-1)
    return depth[..., None] * (uv1 @ pixel_to_camera(intrinsics).T)


def rigid_error(matrix: np.ndarray) -> str | None:
    """What keeps a 4×4 matrix from being a camera pose (a rotation and a translation), or None.

    Checks, within :data:`RIGID_TOLERANCE`: the last row is (0, 0, 0, 1), the 3×3 block is
    orthonormal (no scale, no shear) and its determinant is +1 (no mirror: a pose with one axis
    flipped, as OpenCV axes written into OpenGL ones would be, is refused).
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        return f"expected a 4×4 matrix, got shape {m.shape}"
    if not np.isfinite(m).all():
        return "the 4×4 pose holds NaN or infinite values"
    if np.abs(m[3] - (0, 0, 0, 1)).max() > RIGID_TOLERANCE:
        return f"the last row is {m[3].tolist()}, not [0, 0, 0, 1]"
    rot = m[:3, :3]
    off = np.abs(rot @ rot.T - np.eye(3)).max()
    if off > RIGID_TOLERANCE:
        scales = np.linalg.norm(rot, axis=0).round(6).tolist()
        return (
            f"the rotation block is not orthonormal (|R·Rᵀ − I| up to {off:.2g}; column "
            f"lengths {scales}): not a rigid transform"
        )
    if np.linalg.det(rot) < 0:
        return "the rotation block is a reflection (determinant −1): one camera axis is flipped"
    return None
