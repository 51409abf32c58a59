"""Pairs of frames on disk: which frames pair up, and each frame's geometry or why it has none.

A frame pairs with the next frame of its pass (same mission and viewpoint folder, stems in
order). Carrying its pixels needs its depth PNG, its extrinsics and its dynamic mask; a partial
download may lack some, and the pair is then *unavailable*, with the missing file named, while
everything else of an evaluation goes on (:func:`pair_sums`). Each frame of a pass but the
first and last belongs to two pairs: an evaluation walking a pass can read each frame's geometry
once (:func:`read_geometry`) and hand it to :func:`~claravid.eval.measures.cross_view.cross_view`
for both.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from claravid.data.index import Frame
from claravid.eval.measures.cross_view import CrossViewSums, cross_view
from claravid.infra.errors import CorruptFileError
from claravid.io import modalities
from claravid.io.layout import MISSIONS, frame_file, scaled_intrinsics


def pass_pairs(frames: Sequence[Frame]) -> list[tuple[int, int]]:
    """``(t, s)`` indices into ``frames``: each frame and the next listed frame of its pass.

    A pass is the frames of one mission and viewpoint folder in stem order (consecutive ones
    overlap); with a selection that leaves frames out, a frame pairs with the next one listed.
    """
    passes: dict[tuple[str, str], list[int]] = {}
    for i, frame in enumerate(frames):
        passes.setdefault((frame.mission, frame.viewpoint), []).append(i)
    pairs = []
    for members in passes.values():
        members.sort(key=lambda i: frames[i].stem)
        pairs += list(itertools.pairwise(members))
    return sorted(pairs)


@dataclass(frozen=True)
class FrameGeometry:
    """What carrying a frame's pixels needs: planar depth, pose, dynamic mask, intrinsics."""

    depth: np.ndarray
    c2w: np.ndarray
    dynamic: np.ndarray
    intrinsics: np.ndarray


class GeometryUnavailable(Exception):
    """A frame lacks a file cross-view consistency needs, or one of them is damaged; the message
    says which."""


def read_geometry(root: str | Path, frame: Frame) -> FrameGeometry:
    """Read a frame's depth, extrinsics and dynamic mask from a ClaraVid tree.

    Raises:
        GeometryUnavailable: a file is missing (a partial download) or damaged (unreadable, a
            pose that is not a rigid transform): the message names it.
    """
    mission_dir = Path(root) / MISSIONS[frame.mission]
    paths = {f: frame_file(mission_dir, frame.viewpoint, frame.stem, f) for f in _GEOMETRY}
    missing = [f"{f} ({p})" for f, p in paths.items() if not p.is_file()]
    if missing:
        raise GeometryUnavailable(f"{frame.key} has no {', '.join(missing)}")
    try:
        depth = modalities.read_depth(paths["depth"])
        c2w = modalities.read_extrinsics(paths["extrinsics"])
        dynamic = modalities.read_dynamic_mask(paths["dynamic_mask"])
    except CorruptFileError as error:  # costs this frame's pairs, not the evaluation
        raise GeometryUnavailable(f"{frame.key}: damaged file: {error}") from None
    height, width = depth.shape
    return FrameGeometry(depth, c2w, dynamic, scaled_intrinsics((width, height)))


_GEOMETRY = ("depth", "extrinsics", "dynamic_mask")


def read_pair(root: str | Path, frame_t: Frame, frame_s: Frame) -> tuple[FrameGeometry, ...]:
    """Both frames' geometry, read side by side (the two depth PNGs decode in parallel)."""
    with ThreadPoolExecutor(max_workers=2) as pool:
        return tuple(pool.map(lambda f: read_geometry(root, f), (frame_t, frame_s)))


def pair_sums(
    root: str | Path,
    frame_t: Frame,
    frame_s: Frame,
    pred_t: Any,
    pred_s: Any,
    gt_t: Any,
    gt_s: Any,
    *,
    num_classes: int,
) -> CrossViewSums:
    """:func:`cross_view` of two frames of a ClaraVid tree; unavailable (with the reason) when
    depth, extrinsics or dynamic masks are missing, and nothing else changes."""
    try:
        t, s = read_pair(root, frame_t, frame_s)
    except GeometryUnavailable as error:
        return CrossViewSums.unavailable(str(error), num_classes)
    if t.depth.shape != s.depth.shape:
        return CrossViewSums.unavailable(
            f"{frame_t.key} and {frame_s.key} have depth maps of different sizes", num_classes
        )
    return cross_view(t.depth, s.depth, t.c2w, s.c2w, t.intrinsics, pred_t, pred_s, gt_t, gt_s,
                      t.dynamic, s.dynamic, num_classes=num_classes)  # fmt: skip
