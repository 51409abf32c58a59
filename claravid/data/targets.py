"""Real targets for synthetic-to-real: any folder of images and masks, and UAVid.

``FolderSegmentation`` reads any real UAV segmentation dataset laid out as an image folder
and a mask folder matched by relative path and stem (UDD6, VDD, AeroScapes, your own)::

    ds = FolderSegmentation("/data/udd6/val/src", "/data/udd6/val/gt", palette="udd6")

UAVid on disk::

    <root>/uavid_{train,val,test}/seqN/Images/NNNNNN.png
                                      /Labels/NNNNNN.png   (colour-coded; not in test)

Samples follow ``ClaraVidSegmentation``: ``image`` uint8 [3,H,W], ``mask`` int64 [H,W] train
ids of the palette (255 ignore; absent without masks), ``path``, and ``key`` (the image's
path relative to the dataset root, without extension: evaluation names prediction files
after it); transforms take the whole dict. Masks are decoded by ``claravid.data.masks``: index
masks hold palette ids, colour masks palette colours; unknown values become 255, counted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import torch
from matplotlib.figure import Figure
from torch.utils.data import Dataset

from claravid.data import masks
from claravid.data.palettes import Palette, load_palette
from claravid.data.plot import plot_sample
from claravid.data.samples import Sample, Transform, finish_sample, image_tensor
from claravid.infra.errors import DatasetNotFoundError
from claravid.io import modalities

#: File extensions read as images (compared in lower case).
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
UAVID_SPLITS = ("train", "val", "test", "all")  # all: train and val, the labelled images


def index_folder(folder: Path, what: str) -> dict[str, Path]:
    """Image files under ``folder`` (recursive), keyed by relative path without extension.

    Raises:
        DatasetNotFoundError: the folder does not exist or holds no image.
        ValueError: two files share a key (``a.jpg`` and ``a.png``); the message names both.
    """
    if not folder.is_dir():
        raise DatasetNotFoundError(f"{what} folder", folder)
    found: dict[str, Path] = {}
    for path in sorted(folder.rglob("*")):
        if path.suffix.lower() not in IMAGE_EXTENSIONS or not path.is_file():
            continue
        key = path.relative_to(folder).with_suffix("").as_posix()
        if key in found:
            raise ValueError(
                f"{found[key]} and {path} have the same name but for the extension, so it is "
                f"ambiguous which one is meant; move one out of {folder}"
            )
        found[key] = path
    if not found:
        raise DatasetNotFoundError(f"{what} ({', '.join(IMAGE_EXTENSIONS)} at any depth)", folder)
    return found


def _check_same_size(image: Any, mask: Any, image_path: Path, mask_path: Path) -> None:
    if mask.shape[:2] != image.shape[:2]:
        what = "the mask does not belong to this image (check the folders)"
        # Pixels are read as stored (as PIL does); a photo's EXIF tag may rotate it on screen,
        # where the mask was drawn. Decoded again only on this error path.
        shown = modalities.decode_image(image_path, cv2.IMREAD_GRAYSCALE, exif_orientation=True)
        if shown.shape[:2] != image.shape[:2] and shown.shape[:2] == mask.shape[:2]:
            what = (
                "the image's EXIF orientation tag rotates it to the mask's size on screen, but "
                "its pixels are stored unrotated and read as stored: save the image upright "
                "(e.g. PIL ImageOps.exif_transpose, or exiftran -ai)"
            )
        raise ValueError(
            f"size mismatch: {image_path} is {image.shape[1]}×{image.shape[0]} but its mask "
            f"{mask_path} is {mask.shape[1]}×{mask.shape[0]}; {what}"
        )


class FolderSegmentation(Dataset):
    """Images, and optionally their masks, from two folders matched by relative path and stem.

    Args:
        images: the image folder, searched recursively (any of ``IMAGE_EXTENSIONS``).
        masks: the mask folder, with the same relative paths and stems (any image
            extension but JPEG); None: samples carry no ``mask`` (a target domain to predict
            on or to profile).
        palette: the palette the masks are written in (``udd6``, ``vdd``, ``aeroscapes``,
            ``uavid``, a YAML path or a ``Palette``): single-channel masks hold its ids,
            colour masks its colours. Required with ``masks``.
        transforms: called on each sample dict (see ``claravid.data.transforms``).
        mask_dtype: the masks' dtype: int64 (what a loss takes) or uint8 (255 ignore;
            evaluation keeps masks small until the device); None (default): uint8 with
            ``eval_transforms()``, else int64.

    Raises:
        DatasetNotFoundError: a folder is missing or holds no image.
        FileNotFoundError: an image has no mask; the message names it.
        ValueError: ``masks`` without ``palette``, or two files of one folder share a stem.
    """

    def __init__(
        self,
        images: str | Path,
        masks: str | Path | None = None,
        palette: str | Path | Palette | None = None,
        transforms: Transform | None = None,
        mask_dtype: torch.dtype | None = None,
    ) -> None:
        self.root = Path(images).expanduser()
        self.mask_root = Path(masks).expanduser() if masks is not None else None
        if self.mask_root is not None and palette is None:
            raise ValueError(
                "pass palette= the palette the masks are written in (udd6, vdd, aeroscapes, "
                "uavid, or a YAML path): mask values are its ids, or its colours"
            )
        self.palette = load_palette(palette) if palette is not None else None
        self.transforms = transforms
        self.mask_dtype = mask_dtype
        by_key = index_folder(self.root, "images")
        self.keys = list(by_key)
        self.images = list(by_key.values())
        self.masks: list[Path] | None = None
        if self.mask_root is not None:
            mask_files = index_folder(self.mask_root, "masks")
            missing = [by_key[k] for k in self.keys if k not in mask_files]
            if missing:
                examples = ", ".join(str(p) for p in missing[:3])
                raise FileNotFoundError(
                    f"{len(missing)} image(s) have no mask in {self.mask_root} (same relative "
                    f"path and stem, any image extension), e.g. {examples}; add the masks, or "
                    "move those images out"
                )
            self.masks = [mask_files[k] for k in self.keys]

    @property
    def classes(self) -> tuple[str, ...]:
        """Class names in train-id order (empty without a palette)."""
        return self.palette.names if self.palette is not None else ()

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, index: int) -> Sample:
        path = self.images[index]
        image = modalities.read_rgb(path)
        sample: Sample = {"image": image_tensor(image), "path": str(path), "key": self.keys[index]}
        if self.masks is not None:
            assert self.palette is not None  # __init__ requires one with masks
            mask = masks.read_mask(self.masks[index], self.palette)
            _check_same_size(image, mask, path, self.masks[index])
            sample["mask"] = torch.from_numpy(mask)
        return finish_sample(sample, self.transforms, self.mask_dtype)

    def plot(self, sample: Sample, show_titles: bool = True, suptitle: str | None = None) -> Figure:
        """Image, mask in palette colours, and ``sample["prediction"]`` if any."""
        if self.palette is None:
            raise ValueError("plotting masks needs a palette: pass palette= to the dataset")
        return plot_sample(sample, self.palette, show_titles=show_titles, suptitle=suptitle)


class UAVidSegmentation(Dataset):
    """UAVid images and their labels as palette train ids (test: images only).

    Args:
        root: the folder holding ``uavid_train``, ``uavid_val``, ``uavid_test``.
        split: ``train``, ``val``, ``test`` or ``all`` (train and val: every labelled image).
        palette: ``uavid`` (the default: UAVid's own colour-coded classes), a palette whose
            real side covers UAVid (``syndrone``: UAVid's colours mapped onto its classes), or
            one the label files were converted to.
        transforms: called on each sample dict (see ``claravid.data.transforms``).
        mask_dtype: the masks' dtype: int64 (what a loss takes) or uint8 (255 ignore;
            evaluation keeps masks small until the device); None (default): uint8 with
            ``eval_transforms()``, else int64.
    """

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        palette: str | Path | Palette = "uavid",
        transforms: Transform | None = None,
        mask_dtype: torch.dtype | None = None,
    ) -> None:
        if split not in UAVID_SPLITS:
            raise ValueError(f"unknown UAVid split {split!r}; use one of {', '.join(UAVID_SPLITS)}")
        self.root = Path(root).expanduser()
        self.split = split
        self.transforms = transforms
        self.mask_dtype = mask_dtype
        self.palette = load_palette(palette)
        self.images = []
        for part in ("train", "val") if split == "all" else (split,):
            folder = self.root / f"uavid_{part}"
            if not folder.is_dir():
                raise DatasetNotFoundError(
                    f"UAVid {part} split",
                    folder,
                    "Download UAVid and pass the folder holding uavid_*",
                )
            self.images += sorted(folder.glob("seq*/Images/*.png"))
            if not self.images:
                raise DatasetNotFoundError(f"UAVid {part} images (seq*/Images/*.png)", folder)
        self.has_labels = split != "test"
        if self.has_labels:
            missing = [p for p in self.images if not self.label_path(p).is_file()]
            if missing:
                raise FileNotFoundError(
                    f"{len(missing)} UAVid label(s) missing, e.g. {self.label_path(missing[0])}"
                )

    @staticmethod
    def label_path(image: Path) -> Path:
        """The label file of an image: ``seqN/Labels/<name>`` next to ``seqN/Images/<name>``."""
        return image.parent.parent / "Labels" / image.name

    @property
    def classes(self) -> tuple[str, ...]:
        """Class names in train-id order."""
        return self.palette.names

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, index: int) -> Sample:
        path = self.images[index]
        image = modalities.read_rgb(path)
        sample: Sample = {
            "image": image_tensor(image),
            "path": str(path),
            "key": path.relative_to(self.root).with_suffix("").as_posix(),
            "sequence": path.parent.parent.name,
        }
        if self.has_labels:
            label_path = self.label_path(path)
            mask = masks.read_mask(label_path, self.palette, "uavid")
            _check_same_size(image, mask, path, label_path)
            sample["mask"] = torch.from_numpy(mask)
        return finish_sample(sample, self.transforms, self.mask_dtype)

    def plot(self, sample: Sample, show_titles: bool = True, suptitle: str | None = None) -> Figure:
        """Image, mask in palette colours, and ``sample["prediction"]`` if any."""
        return plot_sample(sample, self.palette, show_titles=show_titles, suptitle=suptitle)
