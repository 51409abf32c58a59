"""The images an evaluation covers: one view over ClaraVid, UAVid and plain folders.

An evaluation needs, per dataset index, more than a sample: the RGB file (for delentropy), the
name its prediction is saved under (``key``,
:func:`claravid.eval.inputs.label_maps.image_key`), the labels alone (the ``--predictions``
path never decodes the image) and the units images are grouped and clustered by
(:mod:`claravid.eval.analysis.units`): ClaraVid mission, viewpoint and spatial block, UAVid
sequence, and every image's parent folder. :class:`EvalData` gathers these behind one interface.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset

from claravid.data import targets
from claravid.data.masks import check_palette_fit
from claravid.data.masks import read_mask as read_label_mask
from claravid.data.palettes import Palette, load_palette
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.eval.analysis.units import DATASETS, group_indices
from claravid.eval.inputs.label_maps import image_key


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
        dataset: samples with uint8 images [3,H,W] (normalised on the model's device, see
            :mod:`claravid.eval.inference.windows`), ``mask``, ``key`` and ``index``.
        paths: the RGB file of each index.
        keys: the prediction name of each index.
        attributes: per-index unit labels (:mod:`claravid.eval.analysis.units`): ``mission``,
            ``viewpoint``, ``block`` (ClaraVid), ``sequence`` (UAVid), ``folder`` (all).
        describe: root, split and dataset kind, for the report's ``source``.
    """

    name: str
    palette: Palette
    dataset: KeyedDataset
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
        """Indices per unit (:func:`claravid.eval.analysis.units.group_indices`)."""
        return group_indices(self.paths, self.attributes, by)


def folder_labels(paths: list[str], root: Path) -> list[str]:
    """Each image's parent folder, relative to the data root (``.`` for the root itself)."""
    return [Path(image_key(Path(p), root)).parent.as_posix() or "." for p in paths]


def _keyed(
    name: str,
    pal: Palette,
    raw: Any,
    paths: list[str],
    keys: list[str],
    read_mask: Callable[[int], Any],
    attributes: dict[str, list[str]] | None = None,
) -> EvalData:
    """The opened dataset as :class:`EvalData`, its uint8 samples keyed."""
    return EvalData(
        name=name,
        palette=pal,
        dataset=KeyedDataset(raw, keys),
        paths=paths,
        keys=keys,
        read_mask_fn=read_mask,
        attributes=attributes or {},
    )


def _claravid(root: Path, split: str, pal: Palette, selection: dict[str, Any]) -> EvalData:
    # Labels through the label cache (prepared by claravid-cache, else built on first read):
    # a whole-frame read of its tiles costs a fraction of decoding the panoptic PNG.
    raw = ClaraVidSegmentation(root, split=split, palette=pal, label_cache=True,
                               mask_dtype=torch.uint8, **selection)  # fmt: skip
    attributes = {
        "mission": [f.mission for f in raw.frames],
        "viewpoint": [f.viewpoint for f in raw.frames],
    }
    with contextlib.suppress(OSError, ValueError):  # blocks need the frames' extrinsics
        attributes["block"] = raw.block_ids()
    return _keyed(
        "claravid",
        pal,
        raw,
        [str(f.paths["rgb"]) for f in raw.frames],
        [f.key for f in raw.frames],
        raw.read_mask,
        attributes,
    )


def _selection_used(raw: ClaraVidSegmentation, selection: dict[str, Any]) -> dict[str, Any]:
    """The report's record of the ClaraVid frames chosen: the missions present, the altitude
    and direction filters (null: all) and the split settings."""
    return {
        "missions": sorted({f.mission for f in raw.frames}),
        "altitude": _as_list(selection.get("altitude")),
        "direction": _as_list(selection.get("direction")),
        "split_config": dataclasses.asdict(raw.split_config),
    }


def _as_list(value: Any) -> list[str] | None:
    if value is None:
        return None
    return [value] if isinstance(value, str) else [str(v) for v in value]


def _uavid(root: Path, split: str, pal: Palette, labels: bool = True) -> EvalData:
    raw = targets.UAVidSegmentation(root, split=split, palette=pal, mask_dtype=torch.uint8)
    if labels:
        if not raw.has_labels:
            raise ValueError(f"UAVid {split} has no labels to evaluate against; use val or train")
        check_palette_fit([raw.label_path(p) for p in raw.images], pal)
    return _keyed(
        "uavid",
        pal,
        raw,
        [str(p) for p in raw.images],
        [image_key(p, root) for p in raw.images],  # as the samples' "key"
        lambda i: read_label_mask(raw.label_path(raw.images[i]), pal),
        {"sequence": [p.parent.parent.name for p in raw.images]},  # seqN/Images/<name>
    )


def _folder(
    root: Path,
    masks: Path | None,
    palette: Any,
    pal: Palette,
    labels: bool = True,
) -> EvalData:
    if labels and masks is None:
        raise ValueError("--dataset folder needs --masks: the folder of label images")
    if labels and palette is None:
        raise ValueError("--dataset folder needs --palette: the palette its masks are written in")

    raw = targets.FolderSegmentation(
        root, masks, palette=pal if masks is not None else None, mask_dtype=torch.uint8
    )
    mask_files = list(raw.masks or [])
    if masks is not None:
        check_palette_fit(mask_files, pal)
    return _keyed(
        "folder",
        pal,
        raw,
        [str(p) for p in raw.images],
        list(raw.keys),
        lambda i: read_label_mask(mask_files[i], pal),
    )


def open_data(
    root: str | Path,
    *,
    dataset: str = "claravid",
    split: str = "val",
    palette: str | Path | None = None,
    masks: str | Path | None = None,
    selection: dict[str, Any] | None = None,
    labels: bool = True,
) -> EvalData:
    """Open the images to evaluate.

    Args:
        root: the ClaraVid root, the folder holding ``uavid_*``, or a folder of images.
        dataset: ``claravid``, ``uavid`` or ``folder``.
        split: ``train``/``val``/``test``/``all`` or a split file (ClaraVid; UAVid has
            train/val/test); ignored for folders.
        palette: palette name or YAML (default ``claravid`` for ClaraVid, ``uavid`` for UAVid;
            required for folders).
        masks: the folder of label images mirroring ``root`` (``folder`` only).
        selection: ClaraVid ``missions``, ``altitude``, ``direction`` and ``split_config``
            (e.g. what a training checkpoint used).
        labels: False opens the images alone (``scores``: no labels, no masks needed).

    Raises:
        ValueError: an unknown dataset kind, or a combination that cannot work.
    """
    if dataset not in DATASETS:
        raise ValueError(f"unknown --dataset {dataset!r}; use one of {', '.join(DATASETS)}")
    root = Path(root).absolute()  # report paths must not depend on the working directory
    pal = load_palette(palette or ("claravid" if dataset == "claravid" else "uavid"))
    describe: dict[str, Any] = {"dataset": dataset, "data": str(root), "split": str(split)}
    if dataset == "claravid":
        data = _claravid(root, split, pal, selection or {})
        raw = data.dataset.dataset
        assert isinstance(raw, ClaraVidSegmentation)  # what _claravid opens
        describe["selection"] = _selection_used(raw, selection or {})
    elif dataset == "uavid":
        data = _uavid(root, split, pal, labels)
    else:
        mask_root = None if masks is None else Path(masks).absolute()
        data = _folder(root, mask_root, palette, pal, labels)
        describe.update(split=None, masks=None if mask_root is None else str(mask_root))
    if not data.paths:
        raise ValueError(f"no images to evaluate in {root} (split {split})")
    data.attributes["folder"] = folder_labels(data.paths, root)
    data.describe = describe
    return data
