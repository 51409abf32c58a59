"""``ClaraVidSegmentation``: ClaraVid frames and palette labels as a torch Dataset.

::

    from claravid import ClaraVidSegmentation
    from claravid.data.transforms import train_transforms

    ds = ClaraVidSegmentation("/data/claravid", split="train", palette="uavid",
                              transforms=train_transforms())
    sample = ds[0]  # {"image": uint8 [3,630,630], "mask": int64 [630,630], "path": ..., ...}

Only the modalities it needs are read: the RGB, the panoptic PNG's class channel, and the
dynamic mask when the palette tells moving from static objects. With training transforms (a
random crop), only the crop is read: the window is drawn from the frame's size in the JPEG
header, the RGB window is decoded alone (:mod:`claravid.io.jpeg_region`, same pixels as a full
decode) and the labels are read by region from the label cache (:mod:`claravid.data.label_cache`);
``sample["crop"]`` says where the crop was cut from.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from matplotlib.figure import Figure
from torch.utils.data import Dataset
from tqdm.auto import tqdm

from claravid.data.blocks import mission_origins
from claravid.data.index import Frame, list_frames
from claravid.data.label_cache import LabelCache, PrepareSummary, png_shape
from claravid.data.palettes import Palette, load_palette
from claravid.data.plot import plot_sample
from claravid.data.samples import Transform, finish_sample, image_tensor
from claravid.data.splits import (
    SPLITS,
    SplitConfig,
    SplitSummary,
    block_ids,
    make_split_config,
    select_split,
    summarize_split,
)
from claravid.data.transforms import CropWindow
from claravid.infra.cachedir import cache_dir
from claravid.io import modalities
from claravid.io.jpeg_region import Photo, image_size, open_photo
from claravid.io.labels import read_label_codes, source_fingerprint, warn_unknown
from claravid.io.layout import MISSIONS, frame_file


class ClaraVidSegmentation(Dataset):
    """Semantic segmentation samples of a ClaraVid selection and split.

    A sample is a dict: ``image`` (uint8 [3,H,W] RGB, the exact pixels, also after the
    default transforms), ``mask`` (int64 [H,W] palette train ids, 255 ignore; uint8 with
    ``eval_transforms()``), ``path`` (the RGB
    file), ``mission``, ``viewpoint`` and ``key`` (``<mission folder>/<viewpoint>/<stem>``).
    Transforms take and return the whole dict (see ``claravid.data.transforms``).

    Args:
        root: the ClaraVid root, holding the mission folders.
        split: ``train``, ``val``, ``test`` (spatial blocks, see ``claravid.data.splits``),
            ``all``, or the path of a text file listing frames.
        missions: mission keys; None: all present.
        altitude: ``low``, ``mid``, ``high``; None: all present (a named key that matches
            no folder is an error listing what exists).
        direction: ``h``, ``v``; None: all present.
        palette: a palette name (``claravid``, ``uavid``), YAML path or ``Palette``.
        transforms: called on each sample dict.
        split_config: block size, fractions, seed, held-out missions (a ``SplitConfig`` or
            a dict of its fields).
        label_cache: keep each frame's label codes as a tiled TIFF under this directory
            (True: ``$CLARAVID_CACHE`` or ``~/.cache/claravid``), read by region; prepared up
            front by :meth:`prepare_label_cache` or ``claravid-cache``, else after the first
            read. Later reads never decode the panoptic RGB PNG.
        skip_incomplete: leave out frames missing a file of a modality it reads (RGB,
            panoptic, dynamic mask), counted in one warning, instead of raising.
        mask_dtype: the masks' dtype: int64 (what a loss takes) or uint8 (255 ignore;
            evaluation keeps masks small until the device); None (default): uint8 with
            ``eval_transforms()``, else int64.
    """

    def __init__(
        self,
        root: str | Path,
        split: str | Path = "train",
        missions: Sequence[str] | None = None,
        altitude: Sequence[str] | str | None = None,
        direction: Sequence[str] | str | None = None,
        palette: str | Path | Palette = "claravid",
        transforms: Transform | None = None,
        *,
        split_config: SplitConfig | dict[str, Any] | None = None,
        label_cache: bool | str | Path = False,
        skip_incomplete: bool = False,
        mask_dtype: torch.dtype | None = None,
    ) -> None:
        self.root = Path(root)
        self.palette = load_palette(palette)
        self.transforms = transforms
        self.mask_dtype = mask_dtype
        self.split = str(split)
        self.split_config = make_split_config(split_config, "split_config.")
        fields = ["rgb", "pan_seg"] + (["dynamic_mask"] if self.palette.uses_dynamic else [])
        frames = list_frames(
            self.root, missions, altitude, direction, fields, skip_incomplete=skip_incomplete
        )
        # The whole selection and its camera positions (read once, when a block split needs
        # them) stay for split_summary().
        self._selection = frames
        self._positions: np.ndarray | None = None
        self.frames: list[Frame] = select_split(
            frames, split, self.split_config, self._camera_positions
        )
        if label_cache is True:
            self.label_cache: LabelCache | None = LabelCache()
        elif label_cache:
            self.label_cache = LabelCache(label_cache)
        else:
            self.label_cache = None

    @property
    def classes(self) -> tuple[str, ...]:
        """Class names in train-id order."""
        return self.palette.names

    def __len__(self) -> int:
        return len(self.frames)

    def _label_sources(self, frame: Frame) -> tuple[Path, Path | None]:
        """A frame's label files: the panoptic PNG, and its dynamic mask if the palette reads it,
        or if the label cache is on and the frame has one (cached codes always carry the dynamic
        flag when it exists, so every palette reads the entries ``claravid-cache`` prepares)."""
        if self.palette.uses_dynamic:
            return frame.paths["pan_seg"], frame.paths["dynamic_mask"]
        if self.label_cache is not None:
            dynamic = frame.paths.get("dynamic_mask") or frame_file(
                self.root / MISSIONS[frame.mission], frame.viewpoint, frame.stem, "dynamic_mask"
            )
            if dynamic.is_file():
                return frame.paths["pan_seg"], dynamic
        return frame.paths["pan_seg"], None

    def _codes(self, index: int, window: CropWindow | None = None) -> np.ndarray:
        """Label codes of the frame, or of a window of it (by region from the cache)."""
        pan_seg, dynamic = self._label_sources(self.frames[index])
        if self.label_cache is not None:
            if window is None:
                codes = self.label_cache.read(pan_seg, dynamic)
            else:
                codes = self.label_cache.read_window(pan_seg, dynamic, *window)
        else:  # a PNG cannot be decoded by region: decode it whole, keep the window
            codes = read_label_codes(pan_seg, dynamic)
            if window is not None:
                x, y, w, h = window
                codes = codes[y : y + h, x : x + w]
        warn_unknown(codes, pan_seg)
        return codes

    def read_mask(self, index: int) -> np.ndarray:
        """The frame's train ids, uint8 H×W (255 ignore), unknown class ids counted."""
        return self.palette.remap(self._codes(index))

    def frame_size(self, index: int) -> tuple[int, int]:
        """The frame's (width, height) from the headers of its RGB and panoptic files (nothing
        decoded).

        Raises:
            ValueError: the two files differ in size (the label does not belong to the image).
        """
        frame = self.frames[index]
        width, height = image_size(frame.paths["rgb"])
        self._check_label_size(frame, (width, height))
        return width, height

    def _check_label_size(self, frame: Frame, size: tuple[int, int]) -> None:
        """Raise when the panoptic PNG's header gives another size than the RGB's ``size``."""
        labels = png_shape(frame.paths["pan_seg"])
        if labels is not None and labels != (size[1], size[0]):
            self._size_mismatch(frame, (size[1], size[0]), labels)

    @staticmethod
    def _size_mismatch(frame: Frame, rgb: tuple[int, int], labels: tuple[int, int]) -> None:
        raise ValueError(
            f"size mismatch: {frame.paths['rgb']} is {rgb[1]}×{rgb[0]} but "
            f"{frame.paths['pan_seg']} is {labels[1]}×{labels[0]}; the label does not belong "
            "to this image (re-extract the frame)"
        )

    def _sample(self, index: int, rgb: np.ndarray, mask: np.ndarray) -> dict[str, Any]:
        frame = self.frames[index]
        return {
            "image": image_tensor(rgb),
            "mask": torch.from_numpy(mask),
            "path": str(frame.paths["rgb"]),
            "mission": frame.mission,
            "viewpoint": frame.viewpoint,
            "key": frame.key,
        }

    def read_window(
        self, index: int, window: CropWindow, photo: Photo | None = None
    ) -> dict[str, Any]:
        """The untransformed sample of one window of frame ``index``: only that window of the
        RGB is decoded (same pixels as a full decode) and only that window of the labels read
        (by region, with the label cache); ``crop`` records the window.

        Args:
            index: the frame.
            window: ``(x, y, width, height)`` in the stored frame's pixels, inside the frame.
            photo: the frame's RGB file, already read (:func:`claravid.io.jpeg_region.open_photo`);
                None: read it here.
        """
        frame = self.frames[index]
        photo = photo if photo is not None else open_photo(frame.paths["rgb"])
        rgb = photo.window(*window)
        sample = self._sample(index, rgb, self.palette.remap(self._codes(index, window)))
        sample["crop"] = tuple(int(v) for v in window)
        return sample

    def __getitem__(self, index: int) -> dict[str, Any]:
        frame = self.frames[index]
        if getattr(self.transforms, "crop", None) is not None:
            # Training transforms: the RGB file is read once, its size taken from its header
            # (and the label PNG's), the crop drawn from it and decoded alone.
            photo = open_photo(frame.paths["rgb"])
            self._check_label_size(frame, photo.size)
            # The crop check above found transforms.
            window = self.transforms.draw_window(*photo.size)  # type: ignore[union-attr]
            sample = self.read_window(index, window, photo)
            return finish_sample(sample, self.transforms, self.mask_dtype)
        rgb = modalities.read_rgb(frame.paths["rgb"])
        mask = self.read_mask(index)
        if mask.shape != rgb.shape[:2]:
            self._size_mismatch(frame, rgb.shape[:2], mask.shape)
        return finish_sample(self._sample(index, rgb, mask), self.transforms, self.mask_dtype)

    def prepare_label_cache(
        self, workers: int = 0, progress: bool = False, shard: tuple[int, int] = (0, 1)
    ) -> PrepareSummary:
        """Build the label-cache entries this dataset's frames are missing (in ``workers``
        processes; only every n-th frame from the k-th with ``shard=(k, n)``), so that no read
        decodes a panoptic PNG; a second call does nothing (``claravid-cache`` calls this).

        Raises:
            ValueError: the dataset was made without ``label_cache``.
        """
        if self.label_cache is None:
            raise ValueError("this dataset has no label cache (label_cache=False)")
        sources = [self._label_sources(frame) for frame in self.frames]
        return self.label_cache.prepare(sources, workers=workers, progress=progress, shard=shard)

    def class_frequencies(self, progress: bool = True) -> np.ndarray:
        """Pixels of each train id over this split (int64 [K]), computed once and cached.

        The cache key covers the palette and every label file's path, size and mtime, so
        any change to the selection or the files recomputes it.
        """
        key = hashlib.sha1(self.palette.lut.tobytes())
        for frame in self.frames:
            key.update(source_fingerprint(*self._label_sources(frame)).encode())
        cache_file = cache_dir() / "class_frequencies" / f"{key.hexdigest()}.json"
        if cache_file.is_file():
            return np.asarray(json.loads(cache_file.read_text())["counts"], dtype=np.int64)
        counts = np.zeros(self.palette.num_classes, dtype=np.int64)
        for index in tqdm(range(len(self)), desc="class frequencies", disable=not progress):
            ids = self.read_mask(index)
            counts += np.bincount(ids.ravel(), minlength=256)[: self.palette.num_classes]
        cache_file.parent.mkdir(parents=True, exist_ok=True)
        cache_file.write_text(json.dumps({"classes": self.classes, "counts": counts.tolist()}))
        return counts

    def _camera_positions(self) -> np.ndarray:
        if self._positions is None:
            self._positions = camera_positions(self.root, self._selection)
        return self._positions

    def split_summary(self) -> SplitSummary:
        """The shares of train/val/test the block split realises on this dataset's selection.

        Per mission and overall: frames, blocks and the share of frames in each split, with
        the targets (``summary.table()`` prints them, ``summary.as_dict()`` for JSON). The
        same whichever of train/val/test (or ``all``) this dataset holds.

        Raises:
            ValueError: the dataset reads a split file, which has no blocks to summarise.
        """
        if self.split not in (*SPLITS, "all"):
            raise ValueError(
                f"split_summary describes the block split; this dataset reads the split file "
                f"{self.split}: count its frames per mission instead"
            )
        return summarize_split(self._selection, self._camera_positions(), self.split_config)

    def block_ids(self) -> list[str]:
        """The spatial block of each of this dataset's frames, e.g. ``"003_urban_1/3_2"``.

        ``claravid.data.splits.block_ids`` at ``split_config.block_size``: the unit the block split
        deals whole, and the cluster of dependent frames for a bootstrap.
        """
        row = {f.key: i for i, f in enumerate(self._selection)}
        everywhere = self._camera_positions()
        positions = everywhere[[row[f.key] for f in self.frames]]
        # The grid the split laid: over the whole selection's extent per mission.
        size = self.split_config.block_size
        origins = mission_origins(self._selection, everywhere, size)
        return block_ids(self.frames, positions, size, origins)

    def plot(
        self,
        sample: dict[str, Any],
        show_titles: bool = True,
        suptitle: str | None = None,
    ) -> Figure:
        """Image, mask in palette colours with a legend, and ``sample["prediction"]`` if any."""
        return plot_sample(sample, self.palette, show_titles=show_titles, suptitle=suptitle)


def camera_positions(root: Path, frames: Sequence[Frame]) -> np.ndarray:
    """Camera x, y (metres, world frame) of each frame, from its extrinsics file."""
    positions = np.empty((len(frames), 2), dtype=np.float64)
    for i, frame in enumerate(frames):
        path = frame_file(root / MISSIONS[frame.mission], frame.viewpoint, frame.stem, "extrinsics")
        if not path.is_file():
            raise FileNotFoundError(
                f"the train/val/test split needs camera positions but {path} is missing; "
                "restore the extrinsics, or use split='all' or a split file"
            )
        positions[i] = modalities.read_extrinsics(path)[:2, 3]
    return positions
