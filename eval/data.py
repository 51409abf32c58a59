"""The images an evaluation covers: one view over ClaraVid, UAVid and plain folders.

An evaluation needs, per dataset index, more than a sample: the RGB file (for delentropy), the
name its prediction is saved under (``key``: ``<mission folder>/<viewpoint>/<stem>`` for
ClaraVid, the image's path relative to the data root without extension otherwise), the labels
alone (the ``--predictions`` path never decodes the image) and, for ClaraVid, the mission and
viewpoint to group by. :class:`EvalData` gathers these behind one interface.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from claravid import targets
from claravid.palettes import Palette, load_palette
from claravid.segmentation import ClaraVidSegmentation
from claravid.transforms import eval_transforms

DATASETS = ("claravid", "uavid", "folder")
GROUP_BY = ("mission", "viewpoint")


class KeyedDataset(Dataset):
    """A dataset whose samples carry ``key`` (the prediction file name) and ``index``."""

    def __init__(self, dataset: Dataset, keys: list[str]) -> None:
        self.dataset = dataset
        self.keys = keys

    def __len__(self) -> int:
        return len(self.keys)

    def __getitem__(self, index: int) -> dict[str, Any]:
        sample = self.dataset[index]
        sample["key"] = self.keys[index]
        sample["index"] = index
        return sample


@dataclass
class EvalData:
    """The evaluated images and how to read each one.

    Attributes:
        name: ``claravid``, ``uavid`` or ``folder``.
        palette: the label palette (train ids, names, colours).
        dataset: samples with normalised images (``eval_transforms``), ``key`` and ``index``.
        raw: the same samples without transforms (uint8 image), for overlays.
        paths: the RGB file of each index.
        keys: the prediction name of each index.
        attributes: per-index ``mission`` / ``viewpoint`` (ClaraVid only).
        describe: root, split and dataset kind, for the report's ``source``.
    """

    name: str
    palette: Palette
    dataset: Dataset
    raw: Dataset
    paths: list[str]
    keys: list[str]
    read_mask_fn: Callable[[int], Any]
    attributes: dict[str, list[str]] = field(default_factory=dict)
    describe: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.paths)

    def read_mask(self, index: int) -> np.ndarray:
        """The labels of image ``index`` as uint8 train ids (255 ignore), image not decoded."""
        mask = self.read_mask_fn(index)
        if isinstance(mask, torch.Tensor):
            mask = mask.numpy()
        mask = np.asarray(mask)
        return mask if mask.dtype == np.uint8 else mask.astype(np.uint8)

    def groups(self, by: str) -> dict[str, list[int]]:
        """Indices per mission or viewpoint, in first-seen order (ClaraVid only)."""
        if by not in self.attributes:
            raise ValueError(
                f"--group-by {by} needs ClaraVid data (missions and viewpoints); "
                f"the {self.name} dataset has none"
            )
        out: dict[str, list[int]] = {}
        for index, value in enumerate(self.attributes[by]):
            out.setdefault(value, []).append(index)
        return out


def _relative_key(path: Path, root: Path) -> str:
    try:
        rel = path.resolve().relative_to(root.resolve())
    except ValueError:
        rel = Path(path.name)
    return rel.with_suffix("").as_posix()


def _accepts(cls: type, name: str) -> bool:
    try:
        return name in inspect.signature(cls).parameters
    except (TypeError, ValueError):
        return False


def _sample_mask(dataset: Dataset) -> Callable[[int], Any]:
    def read(index: int) -> Any:
        sample = dataset[index]
        if "mask" not in sample:
            raise ValueError(f"{sample['path']} has no ground truth: evaluation needs labels")
        return sample["mask"]

    return read


def open_data(
    root: str | Path,
    *,
    dataset: str = "claravid",
    split: str = "val",
    palette: str | Path | None = None,
    masks: str | Path | None = None,
    selection: dict[str, Any] | None = None,
) -> EvalData:
    """Open the images to evaluate.

    Args:
        root: the ClaraVid root, the folder holding ``uavid_*``, or a folder of images.
        dataset: ``claravid``, ``uavid`` or ``folder``.
        split: ``train``/``val``/``test``/``all`` (ClaraVid; UAVid has train/val/test);
            ignored for folders.
        palette: palette name or YAML (default ``claravid`` for ClaraVid, ``uavid`` else).
        masks: the folder of label images mirroring ``root`` (``folder`` only).
        selection: ClaraVid ``missions``, ``altitude``, ``direction`` and ``split_config``
            (e.g. what a training checkpoint used).

    Raises:
        ValueError: an unknown dataset kind, or a combination that cannot work.
    """
    if dataset not in DATASETS:
        raise ValueError(f"unknown --dataset {dataset!r}; use one of {', '.join(DATASETS)}")
    root = Path(root).absolute()  # report paths must not depend on the working directory
    pal = load_palette(palette or ("claravid" if dataset == "claravid" else "uavid"))
    describe: dict[str, Any] = {"dataset": dataset, "data": str(root), "split": split}
    if dataset == "claravid":

        def make(transforms: Any) -> ClaraVidSegmentation:
            return ClaraVidSegmentation(
                root, split=split, palette=pal, transforms=transforms, **(selection or {})
            )

        raw = make(None)
        paths = [str(f.paths["rgb"]) for f in raw.frames]
        keys = [f.key for f in raw.frames]
        attributes = {
            "mission": [f.mission for f in raw.frames],
            "viewpoint": [f.viewpoint for f in raw.frames],
        }
        read_mask: Callable[[int], Any] = raw.read_mask
        transformed: Dataset = make(eval_transforms())
    else:
        if dataset == "uavid":
            cls: Any = targets.UAVidSegmentation
            kwargs: dict[str, Any] = {"split": split}
        else:
            cls = getattr(targets, "FolderSegmentation", None)
            if cls is None:
                raise ValueError(
                    "--dataset folder needs claravid.targets.FolderSegmentation, which this "
                    "installation lacks; update claravid-toolkit"
                )
            kwargs = {"masks": masks}
            describe["split"] = None
            describe["masks"] = None if masks is None else str(masks)
        if _accepts(cls, "palette"):
            kwargs["palette"] = pal
        elif pal.name != "uavid":
            raise ValueError(f"{cls.__name__} reads only the uavid palette, not {pal.name!r}")

        def make(transforms: Any) -> Dataset:
            return cls(root, transforms=transforms, **kwargs)

        raw = make(None)
        paths = [str(p) for p in raw.images]
        keys = [_relative_key(Path(p), root) for p in raw.images]
        attributes = {}
        read_mask = raw.read_mask if hasattr(raw, "read_mask") else _sample_mask(raw)
        transformed = make(eval_transforms())
    if not paths:
        raise ValueError(f"no images to evaluate in {root} (split {split})")
    return EvalData(
        name=dataset,
        palette=pal,
        dataset=KeyedDataset(transformed, keys),
        raw=KeyedDataset(raw, keys),
        paths=paths,
        keys=keys,
        read_mask_fn=read_mask,
        attributes=attributes,
        describe=describe,
    )
