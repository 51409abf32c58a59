"""``ClaravidDataset``: a drop-in for the official ClaraVid SDK's class, decoding faster.

Same constructor, frame order, keys, dtypes, shapes and values as the official SDK
(``claravid.ClaravidDataset`` of PyPI ``claravid``), so code written for it runs unchanged::

    ds = ClaravidDataset("/data/claravid", missions=["urban_1"], altitude=["low"],
                         fields=["rgb", "pan_seg"])
    item = ds[0]  # {"rgb": uint8 H×W×3, "pan_seg": int32 H×W×2, "frame_idx": 0}

Selection as in the SDK: a default (None) means every mission, altitude and direction present
on disk, so partial downloads work. Differences, all additive: a key named explicitly that
matches no folder, and a frame missing one of the requested modalities (whichever one), raise
errors that name what exists or what is missing (the SDK fails later, or returns fewer frames
silently); ``frames`` gives each frame's mission and viewpoint; ``skip_incomplete`` leaves out
frames that miss a modality, counted in one warning.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from claravid.data.index import Frame, list_frames
from claravid.io import modalities
from claravid.io.layout import ALTITUDES, CLASSES, DIRECTIONS, INTRINSICS, MODALITIES


def _as_list(keys: Sequence[str] | str | None) -> list[str]:
    if keys is None:
        return []
    return [keys] if isinstance(keys, str) else list(keys)


class ClaravidDataset:
    """ClaraVid frames as dicts of numpy arrays, keyed by SDK field name plus ``frame_idx``.

    Args:
        root: the ClaraVid root, holding the mission folders.
        missions: mission keys (``rural_1`` … ``urban_high_1``); None: all present.
        altitude: ``low``, ``mid``, ``high``; None: all present.
        direction: ``h``, ``v``; None: all present.
        fields: ``rgb``, ``depth``, ``seg_color``, ``pan_seg``, ``dynamic_mask``,
            ``extrinsics``, ``intrinsics``; None: all.
        paths_func: as in the SDK, a function building the list of per-frame path dicts
            (called with ``root, missions=, fields=, viewpoint_altitude=,
            viewpoint_direction=``); None: the standard layout.
        skip_incomplete: leave out frames that miss a modality (one warning counts them)
            instead of raising an error naming the missing file.
    """

    SEMANTIC_PALLETE = CLASSES  # the SDK's (misspelt) name for the class table
    K = INTRINSICS

    def __init__(
        self,
        root: str | Path,
        missions: Sequence[str] | str | None = None,
        altitude: Sequence[str] | str | None = None,
        direction: Sequence[str] | str | None = None,
        fields: Sequence[str] | str | None = None,
        paths_func: Callable[..., list[dict[str, Path]]] | None = None,
        *,
        skip_incomplete: bool = False,
    ) -> None:
        self.root = Path(root)
        self.frames: list[Frame] = list_frames(
            self.root, missions, altitude, direction, fields, skip_incomplete=skip_incomplete
        )
        self.missions = list(dict.fromkeys(f.mission for f in self.frames))
        self.altitude = _as_list(altitude) or list(ALTITUDES)
        self.direction = _as_list(direction) or list(DIRECTIONS)
        self.fields = list(dict.fromkeys(_as_list(fields))) or list(MODALITIES)
        if paths_func is not None:
            self.path_list = paths_func(
                self.root,
                missions=self.missions,
                fields=self.fields,
                viewpoint_altitude=self.altitude,
                viewpoint_direction=self.direction,
            )
        else:
            self.path_list = [frame.paths for frame in self.frames]

    def __len__(self) -> int:
        return len(self.path_list)

    def __getitem__(self, idx: int) -> dict[str, Any]:
        if not -len(self) <= idx < len(self):
            raise IndexError(f"frame index {idx} out of range for {len(self)} frames")
        idx = idx % len(self)
        item: dict[str, Any] = {name: self._read(name, idx) for name in self.fields}
        item["frame_idx"] = idx
        return item

    def _read(self, name: str, idx: int) -> np.ndarray:
        if name == "intrinsics":
            return modalities.read_intrinsics()
        return modalities.READERS[name](self.path_list[idx][name])

    # The SDK's per-field readers, kept for code that calls them directly.
    def read_rgb(self, idx: int) -> np.ndarray:
        """RGB photo, uint8 H×W×3."""
        return self._read("rgb", idx)

    def read_depth(self, idx: int) -> np.ndarray:
        """Metric depth, float32 H×W, metres in [0, 1000]."""
        return self._read("depth", idx)

    def read_seg_color(self, idx: int) -> np.ndarray:
        """Semantic colour map, uint8 H×W×3."""
        return self._read("seg_color", idx)

    def read_pan_seg(self, idx: int) -> np.ndarray:
        """Panoptic labels, int32 H×W×2: instance id, class id."""
        return self._read("pan_seg", idx)

    def read_dynamic_mask(self, idx: int) -> np.ndarray:
        """Dynamic mask, uint8 H×W: 255 static, 0 dynamic."""
        return self._read("dynamic_mask", idx)

    def read_extrinsics(self, idx: int) -> np.ndarray:
        """Camera-to-world pose, float32 4×4."""
        return self._read("extrinsics", idx)

    def read_intrinsics(self, *_args: object) -> np.ndarray:
        """Pinhole intrinsics at 4032×3024, float32 3×3."""
        return self._read("intrinsics", 0)
