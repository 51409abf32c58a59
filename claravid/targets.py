"""Real targets: UAVid (colour-coded labels) and plain image folders, as torch Datasets.

UAVid on disk::

    <root>/uavid_{train,val,test}/seqN/Images/NNNNNN.png
                                      /Labels/NNNNNN.png   (colour-coded; not in test)

Samples follow ``ClaraVidSegmentation``: ``image`` uint8 [3,H,W], ``mask`` int64 [H,W] in
the ``uavid`` palette (255 ignore), ``path``, ``sequence``; transforms take the whole dict.
A ClaraVid model trained with ``palette="uavid"`` is evaluated on it directly.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from claravid import modalities
from claravid.errors import DatasetNotFoundError
from claravid.palettes import load_palette

Transform = Callable[[dict[str, Any]], dict[str, Any]]
UAVID_SPLITS = ("train", "val", "test")


class UnknownColorWarning(UserWarning):
    """A label image holds colours outside the palette; those pixels were ignored."""


def _sample(image: np.ndarray, path: Path, **extra: Any) -> dict[str, Any]:
    return {"image": torch.from_numpy(image).permute(2, 0, 1), "path": str(path), **extra}


def _finish(sample: dict[str, Any], transforms: Transform | None) -> dict[str, Any]:
    if transforms is not None:
        sample = transforms(sample)
    if "mask" in sample:
        sample["mask"] = sample["mask"].long()
    return sample


class UAVidSegmentation(Dataset):
    """UAVid images and their labels in the ``uavid`` palette (test: images only).

    Args:
        root: the folder holding ``uavid_train``, ``uavid_val``, ``uavid_test``.
        split: ``train``, ``val`` or ``test``.
        transforms: called on each sample dict (see ``claravid.transforms``).
    """

    def __init__(self, root: str | Path, split: str = "val", transforms: Transform | None = None):
        if split not in UAVID_SPLITS:
            raise ValueError(f"unknown UAVid split {split!r}; use one of {', '.join(UAVID_SPLITS)}")
        self.root = Path(root)
        self.split = split
        self.transforms = transforms
        self.palette = load_palette("uavid")
        folder = self.root / f"uavid_{split}"
        if not folder.is_dir():
            raise DatasetNotFoundError(
                f"UAVid {split} split", folder, "Download UAVid and pass the folder holding uavid_*"
            )
        self.images = sorted(folder.glob("seq*/Images/*.png"))
        if not self.images:
            raise DatasetNotFoundError(f"UAVid {split} images (seq*/Images/*.png)", folder)
        self.has_labels = split != "test"
        if self.has_labels:
            missing = [p for p in self.images if not self.label_path(p).is_file()]
            if missing:
                raise FileNotFoundError(
                    f"{len(missing)} UAVid label(s) missing, e.g. {self.label_path(missing[0])}"
                )

    @staticmethod
    def label_path(image: Path) -> Path:
        return image.parent.parent / "Labels" / image.name

    @property
    def classes(self) -> tuple[str, ...]:
        return self.palette.names

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, index: int) -> dict[str, Any]:
        path = self.images[index]
        image = modalities.read_rgb(path)
        sample = _sample(image, path, sequence=path.parent.parent.name)
        if self.has_labels:
            label_path = self.label_path(path)
            mask = self.palette.ids_from_colors(modalities.read_rgb(label_path))
            if mask.shape != image.shape[:2]:
                raise ValueError(
                    f"size mismatch: {path} is {image.shape[1]}×{image.shape[0]} but "
                    f"{label_path} is {mask.shape[1]}×{mask.shape[0]}"
                )
            unknown = int(np.count_nonzero(mask == self.palette.ignore_index))
            if unknown:
                warnings.warn(
                    f"{unknown} pixel(s) of {label_path} have colours outside the UAVid "
                    "palette; they are ignored",
                    UnknownColorWarning,
                    stacklevel=2,
                )
            sample["mask"] = torch.from_numpy(mask)
        return _finish(sample, self.transforms)


class ImageFolder(Dataset):
    """Unlabelled images under a folder (a target domain to predict on or to profile).

    Args:
        root: the folder.
        pattern: a glob, ``**`` recurses (default: JPEG and PNG files at any depth).
        transforms: called on each sample dict (``image``, ``path``).
    """

    def __init__(
        self, root: str | Path, pattern: str | None = None, transforms: Transform | None = None
    ):
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetNotFoundError("image folder", self.root)
        patterns = [pattern] if pattern else ["**/*.jpg", "**/*.jpeg", "**/*.png"]
        self.images = sorted({p for pat in patterns for p in self.root.glob(pat) if p.is_file()})
        if not self.images:
            raise DatasetNotFoundError(f"images matching {' or '.join(patterns)}", self.root)
        self.transforms = transforms

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, index: int) -> dict[str, Any]:
        path = self.images[index]
        return _finish(_sample(modalities.read_rgb(path), path), self.transforms)
