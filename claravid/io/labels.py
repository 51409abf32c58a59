"""From panoptic PNGs to label codes: one uint8 image per frame that every palette reads.

A *label code* folds the ClaraVid class id and the dynamic flag into one byte, so a palette
reduction (even one that splits static and moving vehicles) is a single 256-entry lookup:

- a known class id ``c`` on a static pixel: ``c`` (0…22, or 255 for Unlabeled);
- a known class id ``c`` on a dynamic pixel: ``c + 128`` (Unlabeled stays 255);
- an id outside the ClaraVid class table: ``UNKNOWN_CODE`` (254), ignored and counted.

Codes are cheap to cache: ``claravid.data.label_cache.LabelCache`` keeps them as tiled TIFFs read by
window, each named after and recording its source files' identity (:func:`source_identity`:
path, size and modification time) so an edited source is never served stale.
"""

from __future__ import annotations

import warnings
from hashlib import sha1
from pathlib import Path

import cv2
import numpy as np

from claravid.io import modalities
from claravid.io.layout import CLASS_BY_ID, DYNAMIC_MASK_DYNAMIC, UNLABELED_ID

DYNAMIC_OFFSET = 128
UNKNOWN_CODE = 254


class UnknownClassWarning(UserWarning):
    """Pixels carried class ids outside the ClaraVid class table; they were ignored."""


def _code_tables() -> tuple[np.ndarray, np.ndarray]:
    static = np.full(256, UNKNOWN_CODE, dtype=np.uint8)
    for class_id in CLASS_BY_ID:
        static[class_id] = class_id
    dynamic = static.copy()
    known = [c for c in CLASS_BY_ID if c != UNLABELED_ID]
    dynamic[known] = np.asarray(known) + DYNAMIC_OFFSET
    return static, dynamic


STATIC_CODES, DYNAMIC_CODES = _code_tables()


def label_codes(semantic: np.ndarray, dynamic_mask: np.ndarray | None = None) -> np.ndarray:
    """Class ids (uint8 H×W, the panoptic R channel) and an optional dynamic mask -> codes."""
    codes = cv2.LUT(semantic, STATIC_CODES)
    if dynamic_mask is not None:
        if dynamic_mask.shape != semantic.shape:
            raise ValueError(
                f"dynamic mask is {dynamic_mask.shape[1]}×{dynamic_mask.shape[0]} but the "
                f"labels are {semantic.shape[1]}×{semantic.shape[0]}"
            )
        moving = dynamic_mask == DYNAMIC_MASK_DYNAMIC
        codes[moving] = DYNAMIC_CODES[semantic[moving]]
    return codes


def read_label_codes(pan_seg: str | Path, dynamic_mask: str | Path | None = None) -> np.ndarray:
    """Read a frame's label codes from its panoptic PNG (and dynamic mask, when given)."""
    semantic = modalities.read_semantic(pan_seg)
    mask = None
    if dynamic_mask is not None:
        mask = modalities.read_dynamic_mask(dynamic_mask)
        if mask.shape != semantic.shape:
            raise ValueError(
                f"size mismatch: {dynamic_mask} is {mask.shape[1]}×{mask.shape[0]} but "
                f"{pan_seg} is {semantic.shape[1]}×{semantic.shape[0]}; the files do not belong "
                "to the same frame"
            )
    return label_codes(semantic, mask)


def warn_unknown(codes: np.ndarray, source: str | Path) -> int:
    """Count pixels of unknown class ids and warn once per file; returns the count."""
    count = int(np.count_nonzero(codes == UNKNOWN_CODE))
    if count:
        warnings.warn(
            f"{count} pixel(s) of {source} carry class ids outside the ClaraVid class table; "
            "they are ignored",
            UnknownClassWarning,
            stacklevel=3,
        )
    return count


def _file_identity(path: Path) -> str:
    """``<resolved path>:<size>:<mtime ns>``: what changes when a file is replaced or edited."""
    stat = path.stat()
    return f"{path.resolve()}:{stat.st_size}:{stat.st_mtime_ns}"


def source_identity(
    pan_seg: str | Path, dynamic_mask: str | Path | None = None
) -> dict[str, str | None]:
    """The staleness key of a frame's label codes: each label file's identity.

    ``{"pan_seg": "<resolved path>:<size>:<mtime ns>", "dynamic_mask": the same, or None when
    the codes are read without a dynamic mask}``. A label-cache entry records it and is served
    only to the same sources (see ``claravid.data.label_cache``).

    Raises:
        OSError: a file is missing or cannot be looked at.
    """
    return {
        "pan_seg": _file_identity(Path(pan_seg)),
        "dynamic_mask": None if dynamic_mask is None else _file_identity(Path(dynamic_mask)),
    }


def identity_fingerprint(identity: dict[str, str | None]) -> str:
    """A short hash of a :func:`source_identity` (the name of its label-cache entry)."""
    return sha1("|".join(v for v in identity.values() if v is not None).encode()).hexdigest()[:16]


def source_fingerprint(*paths: Path | None) -> str:
    """A short hash of files' resolved paths, sizes and mtimes (None entries skipped)."""
    parts = [_file_identity(Path(path)) for path in paths if path is not None]
    return sha1("|".join(parts).encode()).hexdigest()[:16]
