"""Read and write every ClaraVid modality, value for value as the official SDK does.

Decoding goes through OpenCV (`cv2.imdecode`), which is faster than the SDK's PIL path, and
for sequential JPEG photos through the libjpeg decoder of :mod:`claravid.io.jpeg_region` when it
is built (the same pixels as OpenCV's); the results are identical for the lossless PNG/JSON
modalities, and the JPEG RGB may differ only by decoder rounding. Every reader raises
:class:`CorruptFileError` naming the file when it is truncated or undecodable (OpenCV alone would
hand back a partly grey image for a truncated JPEG), ``UnsupportedFileError`` for files no reader
decodes (more than 2^30 pixels, 12-bit or arithmetic-coded JPEG; see
:mod:`claravid.io.headers`) and ``FileNotFoundError`` naming it when it is missing. The bytes are
read and checked by :mod:`claravid.io.imagefile`.

The writers produce the exact on-disk encodings (used by the scene generator and tests).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from claravid.infra.errors import CorruptFileError
from claravid.io.imagefile import (
    PNG_COLOR_TYPES,
    decode_bytes,
    describe_bytes,
    png_header,
    read_checked,
)
from claravid.io.imagefile import decode_image as decode_image  # re-exported: where callers look
from claravid.io.imagefile import read_bytes as read_bytes
from claravid.io.jpeg_region import read_rgb
from claravid.io.layout import DEPTH_MAX_M, DEPTH_SCALE, INTRINSICS, rigid_error


def _decode_png8(
    path: str | Path, flags: int, color_types: frozenset[int], expected: str
) -> np.ndarray:
    """Decode a label PNG after checking, from its header, that it has the documented encoding.

    The header check costs nothing next to decoding, and catches what OpenCV would silently
    convert: 16-bit files (scaled to 8 bits), grey or palette files (expanded to colour), and
    JPEG bytes under a ``.png`` name (lossy: label values change at every edge).
    """
    data = read_checked(path)
    header = png_header(data)
    if header is None or header[0] != 8 or header[1] not in color_types:
        raise CorruptFileError(path, f"expected {expected}, found {describe_bytes(data)}")
    return decode_bytes(data, path, flags, checked=True)


_RGB_TYPES = frozenset({2, 6})  # RGBA: the same R, G, B bytes; alpha is ignored
_ANY_TYPE = frozenset(PNG_COLOR_TYPES)

_PAN_SEG = "an 8-bit RGB PNG (R class id, G + 256·B instance id)"
_DEPTH = "an 8-bit RGB PNG (24-bit depth code over R, G, B)"
_DYNAMIC = "an 8-bit PNG mask (255 static, 0 dynamic)"


def read_seg_color(path: str | Path) -> np.ndarray:
    """The semantic colour map (for viewing): uint8 H×W×3, RGB order."""
    return read_rgb(path)


def read_depth(path: str | Path) -> np.ndarray:
    """Metric depth: float32 H×W metres = (R + 256·G + 65536·B) / (2^24 − 1) × 1000.

    Computed in float32 in the SDK's order (sum, divide, multiply) so values are bit-equal.
    """
    bgr = _decode_png8(path, cv2.IMREAD_COLOR, _RGB_TYPES, _DEPTH)
    # R, G, B, 255 bytes read as one little-endian int32: code + 255·2^24 - 2^32 = code - 2^24,
    # exact in float32 (|value| <= 2^24), and so is adding 2^24 back: the 24-bit code, exactly.
    shifted = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGBA).view("<i4")[..., 0]
    depth = np.empty(shifted.shape, np.float32)
    np.add(shifted, np.float32(1 << 24), out=depth, dtype=np.float32, casting="unsafe")
    depth /= np.float32(DEPTH_SCALE)
    depth *= np.float32(DEPTH_MAX_M)
    return depth


def read_pan_seg(path: str | Path) -> np.ndarray:
    """Panoptic labels: int32 H×W×2; ``[..., 0]`` instance (G + 256·B), ``[..., 1]`` class (R).

    The file must be an 8-bit RGB (or RGBA) PNG; anything else (16-bit, grey, palette, JPEG
    bytes) is a ``CorruptFileError`` naming the file, never silently wrong labels.
    """
    bgr = _decode_png8(path, cv2.IMREAD_COLOR, _RGB_TYPES, _PAN_SEG)
    pan = np.empty((*bgr.shape[:2], 2), dtype=np.int32)
    np.left_shift(bgr[..., 0], 8, out=pan[..., 0], dtype=np.int32)
    pan[..., 0] += bgr[..., 1]
    pan[..., 1] = bgr[..., 2]
    return pan


def read_semantic(path: str | Path) -> np.ndarray:
    """Only the class ids of a panoptic PNG: uint8 H×W (the R channel), without the int32 pair."""
    bgr = _decode_png8(path, cv2.IMREAD_COLOR, _RGB_TYPES, _PAN_SEG)
    return np.ascontiguousarray(bgr[..., 2])


def read_dynamic_mask(path: str | Path) -> np.ndarray:
    """The dynamic mask: uint8 H×W, 255 static and 0 dynamic.

    Converted like PIL's ``convert('L')``: grey files as they are; colour files with PIL's
    ITU-R 601-2 integer luma (which differs from OpenCV's in rounding). Anything but an 8-bit
    PNG (16-bit, JPEG bytes) is a ``CorruptFileError`` naming the file.
    """
    image = _decode_png8(path, cv2.IMREAD_UNCHANGED, _ANY_TYPE, _DYNAMIC)
    if image.ndim == 2:
        return image
    b, g, r = (image[..., i].astype(np.uint32) for i in range(3))
    return ((r * 19595 + g * 38470 + b * 7471 + 0x8000) >> 16).astype(np.uint8)


def read_extrinsics(path: str | Path) -> np.ndarray:
    """The camera-to-world pose: float32 4×4, OpenGL camera axes (see :mod:`claravid.io.layout`).

    Raises:
        CorruptFileError: naming the file, when it is not a 4×4 list of numbers, or holds NaN or
            infinities, or is not a rigid transform (scale, shear, a mirrored axis, a last row
            other than 0, 0, 0, 1): such a pose would put every pixel of the frame elsewhere.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"file not found: {path}")
    try:
        matrix = np.asarray(json.loads(path.read_text()), dtype=np.float64).reshape(4, 4)
    except (ValueError, TypeError) as error:
        raise CorruptFileError(path, f"expected a 4×4 nested list of numbers ({error})") from None
    with np.errstate(over="ignore"):  # beyond float32's range: inf, rejected just below
        pose = matrix.astype(np.float32)
    # JSON readers accept NaN and Infinity; a pose with them would put frames nowhere.
    if not np.isfinite(pose).all():
        raise CorruptFileError(path, "the 4×4 pose holds NaN or infinite values")
    problem = rigid_error(matrix)
    if problem is not None:
        raise CorruptFileError(path, f"not a camera pose: {problem}")
    return pose


def read_intrinsics(*_args: object) -> np.ndarray:
    """The pinhole intrinsics (no files): float32 3×3."""
    return INTRINSICS.copy()


#: SDK field key -> its reader (a file path in, the decoded array out).
READERS: dict[str, Callable[[str | Path], np.ndarray]] = {
    "rgb": read_rgb,
    "depth": read_depth,
    "seg_color": read_seg_color,
    "pan_seg": read_pan_seg,
    "dynamic_mask": read_dynamic_mask,
    "extrinsics": read_extrinsics,
    "intrinsics": read_intrinsics,
}


# --------------------------------------------------------------------------------------------
# Writers: the exact on-disk encodings.


def _write_image(path: str | Path, image: np.ndarray, params: list[int] | None = None) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ok, data = cv2.imencode(path.suffix, image, params or [])
    if not ok:
        raise ValueError(f"OpenCV could not encode {path}")
    data.tofile(path)


def write_rgb(path: str | Path, rgb: np.ndarray, quality: int = 95) -> None:
    """Write a uint8 H×W×3 RGB image as JPEG."""
    _write_image(path, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])


def write_seg_color(path: str | Path, colors: np.ndarray) -> None:
    """Write a uint8 H×W×3 RGB colour map as PNG."""
    _write_image(path, cv2.cvtColor(colors, cv2.COLOR_RGB2BGR))


def encode_depth(depth_m: np.ndarray) -> np.ndarray:
    """Metres -> the 24-bit RGB code (truncating, as the SDK's serializer does)."""
    code = (np.asarray(depth_m, dtype=np.float64) / DEPTH_MAX_M * DEPTH_SCALE).astype(np.int64)
    code = np.clip(code, 0, DEPTH_SCALE)
    return np.stack([code & 0xFF, (code >> 8) & 0xFF, (code >> 16) & 0xFF], -1).astype(np.uint8)


def write_depth(path: str | Path, depth_m: np.ndarray) -> None:
    """Write metric depth (H×W, metres in [0, 1000]) as a 24-bit RGB PNG."""
    _write_image(path, cv2.cvtColor(encode_depth(depth_m), cv2.COLOR_RGB2BGR))


def write_pan_seg(path: str | Path, semantic: np.ndarray, instance: np.ndarray) -> None:
    """Write class ids (R) and instance ids (G + 256·B) as an RGB PNG."""
    instance = np.asarray(instance, dtype=np.int64)
    if instance.min(initial=0) < 0 or instance.max(initial=0) > 0xFFFF:
        raise ValueError("instance ids must be in [0, 65535]")
    rgb = np.stack(
        [np.asarray(semantic, dtype=np.uint8), instance & 0xFF, instance >> 8], -1
    ).astype(np.uint8)
    _write_image(path, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def write_dynamic_mask(path: str | Path, mask: np.ndarray) -> None:
    """Write a uint8 H×W mask (255 static, 0 dynamic) as a grey PNG."""
    _write_image(path, np.asarray(mask, dtype=np.uint8))


def write_extrinsics(path: str | Path, matrix: np.ndarray) -> None:
    """Write a 4×4 camera-to-world matrix as a JSON nested list."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(np.asarray(matrix, dtype=np.float64).reshape(4, 4).tolist()))
