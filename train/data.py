"""Training data: the datasets a config names, k augmented crops per frame, the loader, class
weights. Which frame comes when is `claravid.train.sampler`'s business.
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any, Protocol, TypeAlias

import numpy as np
import torch
from omegaconf import DictConfig
from torch.utils.data import DataLoader, Dataset

from claravid.data.label_cache import CacheWriteError
from claravid.data.masks import read_mask
from claravid.data.real_layouts import LAYOUT_DATASETS, RealSegmentation
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.splits import SPLITS
from claravid.data.targets import UAVidSegmentation
from claravid.data.transforms import AugmentConfig, train_transforms
from claravid.io import jpeg_region
from claravid.models.backbones.specs import backbone_spec
from claravid.models.heads.specs import check_norm_batch, head_spec
from claravid.train.config import to_plain
from claravid.train.sampler import StepSampler

#: A training or validation split, as the builders below make it.
SegmentationSplit: TypeAlias = ClaraVidSegmentation | UAVidSegmentation | RealSegmentation


class SampleDataset(Protocol):
    """A map-style dataset of samples (dicts) with a length: what the crops read."""

    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> Any: ...  # fmt: skip


class EmptySplitError(ValueError):
    """A dataset split with no frame in it."""


class UnreadableLabelsError(ValueError):
    """Frames whose label files cannot be read: training would stop at the first of them."""


#: What a cache folder that cannot take any entry advises a training run to do.
CACHE_ADVICE = (
    "set CLARAVID_CACHE=DIR to a writable folder, or data.label_cache=false to decode the "
    "PNGs every epoch"
)


def _augment(cfg: DictConfig) -> AugmentConfig:
    return AugmentConfig(**to_plain(cfg.data.augment, resolve=False))


def _claravid(cfg: DictConfig, root: str | Path, split: str) -> ClaraVidSegmentation:
    d = cfg.data
    return ClaraVidSegmentation(
        root,
        split=split,
        missions=list(d.missions) if d.missions is not None else None,
        altitude=list(d.altitude) if d.altitude is not None else None,
        direction=list(d.direction) if d.direction is not None else None,
        palette=d.palette,
        split_config={
            "block_size": d.split.block_size,
            "fractions": tuple(d.split.fractions),
            "seed": d.split.seed,
            "val_missions": tuple(d.split.val_missions),
            "test_missions": tuple(d.split.test_missions),
        },
        label_cache=d.label_cache,
        mask_dtype=torch.uint8,  # crops and validation make what they need of it
    )


def _check_root(root: str | None, key: str) -> Path:
    if root is None or not Path(root).is_dir():
        raise FileNotFoundError(
            f"{key}={root} is not a folder: point {key} at the dataset root "
            f"(e.g. {key}=/data/claravid; `make demo` generates one at runs/demo/data)"
        )
    return Path(root)


def _split(cfg: DictConfig, kind: str, root: Path, split: str) -> SegmentationSplit:
    """One split of ClaraVid, UAVid or another real dataset, uint8 images and masks without
    transforms (the one branch both builders share: training crops them in `CropDataset`,
    validation normalises them on the model's device)."""
    if kind == "uavid":
        return UAVidSegmentation(
            root, split=split, palette=cfg.data.palette, mask_dtype=torch.uint8
        )
    if kind in LAYOUT_DATASETS:
        return RealSegmentation(
            root, kind, split=split, palette=cfg.data.palette, mask_dtype=torch.uint8
        )
    return _claravid(cfg, root, split)


def build_train_dataset(cfg: DictConfig) -> SegmentationSplit:
    """The training split, without transforms (`CropDataset` augments it).

    Raises:
        FileNotFoundError: ``data.root`` missing.
        EmptySplitError: the split selects no frame.
    """
    root = _check_root(cfg.data.root, "data.root")
    ds = _split(cfg, cfg.data.dataset, root, cfg.data.train_split)
    if len(ds) == 0:
        raise EmptySplitError(
            f"the {cfg.data.train_split!r} split of {root} holds no frame with this selection "
            "(data.missions/altitude/direction/split); widen the selection or change data.split"
        )
    return ds


def build_val_dataset(cfg: DictConfig) -> SegmentationSplit:
    """The validation split, uint8 frames without transforms: the validation windows normalise
    them on the model's device (``val_window``'s mean and std are ``data.augment``'s)."""
    key = "data.val_root" if cfg.data.val_root is not None else "data.root"
    root = _check_root(cfg.data.val_root or cfg.data.root, key)
    ds = _split(cfg, cfg.data.val_dataset, root, cfg.data.val_split)
    if len(ds) == 0:
        raise EmptySplitError(
            f"the {cfg.data.val_split!r} split of {root} holds no frame with this selection; "
            "widen the selection or change data.split (validation needs images)"
        )
    return ds


def prepare_label_caches(datasets: list[Dataset], workers: int, say: Any = print) -> None:
    """Build the label-cache entries the ClaraVid datasets miss, before the first step, so no
    epoch decodes a panoptic PNG (``claravid-cache`` does the same ahead of time). Says what
    was built and how large the cache is, and which entries could not be written (their
    frames are then decoded from the PNGs).

    Raises:
        UnreadableLabelsError: some frames' label files cannot be read (a truncated PNG, a
            missing dynamic mask): named now, not by a worker's traceback in the first epoch.
        CacheWriteError: the cache folder cannot take any entry (read-only, full disk).
    """
    unreadable: dict[str, str] = {}
    roots: list[str] = []
    for dataset in datasets:
        if isinstance(dataset, ClaraVidSegmentation) and dataset.label_cache is not None:
            try:
                summary = dataset.prepare_label_cache(workers=workers)
            except CacheWriteError as exc:
                error = CacheWriteError(exc.reason, exc.written, CACHE_ADVICE)
                error.errno = exc.errno
                raise error from None
            unreadable.update(summary.failed)
            if summary.failed:
                roots.append(shlex.quote(str(dataset.root)))
            if summary.built:
                say(
                    f"label cache: {summary.built} frame(s) prepared in {summary.seconds:.1f} s, "
                    f"{summary.bytes_per_frame / 1e3:.0f} kB per frame, in {summary.directory}"
                )
            if summary.unwritten:
                pan, reason = summary.unwritten[0]
                more = len(summary.unwritten) - 1
                say(
                    f"label cache: {len(summary.unwritten)} entr{'y' if not more else 'ies'} "
                    f"could not be written ({reason}{f'; and {more} more' if more else ''}); "
                    "those frames are decoded from their PNGs"
                )
    if unreadable:
        pan, reason = next(iter(unreadable.items()))
        first = reason if pan in reason else f"{pan}: {reason}"
        others = f"; and {len(unreadable) - 1} more" if len(unreadable) > 1 else ""
        raise UnreadableLabelsError(
            f"the label files of {len(unreadable)} frame(s) cannot be read, and training would "
            f"stop at them: {first}{others} (claravid-cache --data {roots[0]} lists them all)"
        )


def split_table(dataset: Dataset) -> str | None:
    """The realised train/val/test shares of a ClaraVid block split, for the log; else None."""
    if isinstance(dataset, ClaraVidSegmentation) and dataset.split in SPLITS:
        return dataset.split_summary().table()
    return None


def image_paths(dataset: SegmentationSplit) -> list[str]:
    """Each sample's RGB file, without decoding anything (for complexity)."""
    if isinstance(dataset, ClaraVidSegmentation):
        return [str(f.paths["rgb"]) for f in dataset.frames]
    return [str(p) for p in dataset.images]


class CropDataset(Dataset):
    """k augmented crops of one frame per item, each crop from its own seed.

    A dataset that reads windows (``ClaraVidSegmentation.read_window``) decodes each crop's
    window alone: the window is drawn from the frame's size in its headers, then only those
    pixels of the JPEG and of the label cache are read (same pixels as a full decode). Other
    datasets, or any dataset when the window decoder is not built, decode the frame once per
    item and every crop is cut from it. Either way the window and the augmentations after it
    come from the crop's seed alone, so both give the same crops, and a resumed run draws
    exactly the crops an uninterrupted one does.

    An item is ``{"image": uint8 [k,3,h,w], "mask": uint8 [k,h,w]}``: the training step
    normalises the images (``claravid.data.samples.normalise``) and widens the masks on the device.

    Args:
        base: a dataset of uint8 samples (no transforms).
        augment: the augmentation config (crop size, probabilities ...).
        crops_per_frame: k.
        by_window: read windows (True) or cut crops from full frames (False); None: windows
            when the dataset reads them and the JPEG window decoder is built.
    """

    def __init__(
        self,
        base: SampleDataset,
        augment: AugmentConfig,
        crops_per_frame: int = 1,
        by_window: bool | None = None,
    ) -> None:
        self.base = base
        self.transform = train_transforms(augment, normalize=False)  # normalised on the device
        self.k = crops_per_frame
        if by_window is None:
            fast = jpeg_region.decoder() == jpeg_region.REGION_DECODE
            by_window = fast and hasattr(base, "read_window")
        self.by_window = by_window

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, item: tuple[int, int]) -> dict[str, torch.Tensor]:
        index, seed = item
        # By_window: a dataset that reads windows.
        size = self.base.frame_size(index) if self.by_window else None  # type: ignore[attr-defined]
        frame = {} if self.by_window else self.base[index]
        images, masks = [], []
        for j in range(self.k):
            # Seeding the pipeline per crop makes the crop a function of (position, j) alone.
            self.transform.pipeline.set_random_seed((seed + j) % 2**32)
            if size is not None:
                window = self.transform.draw_window(*size)
                # By_window: a dataset that reads windows.
                sample = self.base.read_window(index, window)  # type: ignore[attr-defined]
            else:
                sample = {"image": frame["image"], "mask": frame["mask"]}
            out = self.transform({k: sample[k] for k in ("image", "mask", "crop") if k in sample})
            images.append(out["image"])
            masks.append(out["mask"])
        return {"image": torch.stack(images), "mask": torch.stack(masks)}


def collate_crops(items: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Concatenate the k crops of each frame into one batch [B·k, ...]."""
    return {key: torch.cat([it[key] for it in items]) for key in ("image", "mask")}


def check_batch(cfg: DictConfig, world_size: int) -> int:
    """Frames per optimiser step; raises unless the batch splits into ranks × micro-batches × k."""
    t, k = cfg.train, cfg.data.crops_per_frame
    per_step = world_size * t.grad_accum * k
    if t.batch_size % per_step:
        raise ValueError(
            f"train.batch_size={t.batch_size} must be a multiple of ranks ({world_size}) × "
            f"train.grad_accum ({t.grad_accum}) × data.crops_per_frame ({k}) = {per_step}"
        )
    least = head_spec(cfg.model.head).min_micro_batch
    micro = t.batch_size // (world_size * t.grad_accum)
    if micro < least:
        raise ValueError(
            f"model.head={cfg.model.head} trains BatchNorm on pooled features and needs at least "
            f"{least} crops per forward pass; train.batch_size={t.batch_size} over {world_size} "
            f"rank(s) × train.grad_accum={t.grad_accum} gives {micro}: raise train.batch_size or "
            "lower train.grad_accum"
        )
    patch = (
        int(cfg.model.backbone_kwargs.get("patch_size", 0))
        or backbone_spec(cfg.model.backbone).patch_size
    )
    a = cfg.data.augment
    fix = "raise train.batch_size or data.augment.crop_height/crop_width"
    check_norm_batch(cfg.model.head, micro, a.crop_height // patch, a.crop_width // patch, fix)
    return t.batch_size // k


def build_train_loader(
    dataset: SampleDataset,
    cfg: DictConfig,
    *,
    rank: int = 0,
    world_size: int = 1,
    start_step: int = 0,
    pin_memory: bool = False,
    groups: list[list[int]] | None = None,
) -> DataLoader:
    """An endless loader of micro-batches for this rank, starting at ``start_step``.

    ``groups``: frame indices per delentropy bin for ``data.sampler: complexity_balanced``.
    """
    t, k = cfg.train, cfg.data.crops_per_frame
    frames_per_step = check_batch(cfg, world_size)
    sampler = StepSampler(
        len(dataset), frames_per_step, cfg.seed, rank, world_size, t.grad_accum, start_step, groups
    )
    workers = cfg.data.num_workers
    return DataLoader(
        CropDataset(dataset, _augment(cfg), k),
        batch_size=sampler.micro,
        sampler=sampler,
        num_workers=workers,
        collate_fn=collate_crops,
        pin_memory=pin_memory,
        # No cv2.setNumThreads(1) in the workers: in a child forked after the parent used
        # OpenCV's thread pool (delentropy of the val set) it deadlocks.
        persistent_workers=workers > 0,
        prefetch_factor=4 if workers > 0 else None,
    )


def class_frequencies(dataset: SampleDataset, num_classes: int) -> np.ndarray:
    """Pixels per class of the training split (ClaraVid's are cached; others counted here)."""
    if isinstance(dataset, ClaraVidSegmentation):
        return dataset.class_frequencies(progress=False)
    counts = np.zeros(num_classes, dtype=np.int64)
    for i in range(len(dataset)):
        if isinstance(dataset, UAVidSegmentation):  # the label file alone, not the image
            path = dataset.label_path(dataset.images[i])
            mask = read_mask(path, dataset.palette, "uavid").ravel()
        elif isinstance(dataset, RealSegmentation):
            mask = dataset.read_mask(i).numpy().ravel()
        else:
            mask = dataset[i]["mask"].numpy().ravel()
        counts += np.bincount(mask[mask < num_classes], minlength=num_classes)
    return counts


def class_weights(counts: np.ndarray, method: str) -> torch.Tensor | None:
    """Loss weights per class from pixel counts; classes absent from training get 0.

    - ``none``: no weighting (None).
    - ``inverse``: 1/frequency, scaled to mean 1 over present classes.
    - ``median_frequency``: median(frequency)/frequency (Eigen & Fergus; SegNet).
    - ``log_inverse``: 1/ln(1.02 + frequency) (ENet), in [1, ~50].
    """
    if method == "none":
        return None
    counts = np.asarray(counts, dtype=np.float64)
    present = counts > 0
    if not present.any():
        raise ValueError("the training split has no labelled pixel: cannot weight classes")
    freq = counts / counts.sum()
    w = np.zeros_like(freq)
    if method == "inverse":
        w[present] = 1.0 / freq[present]
        w[present] /= w[present].mean()
    elif method == "median_frequency":
        w[present] = np.median(freq[present]) / freq[present]
    elif method == "log_inverse":
        w[present] = 1.0 / np.log(1.02 + freq[present])
    else:
        raise ValueError(f"unknown class weighting {method!r}")
    return torch.tensor(w, dtype=torch.float32)
