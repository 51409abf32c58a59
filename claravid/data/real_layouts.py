"""UDD5, UDD6, VDD, AeroScapes and ICG as they are laid out on disk, by split.

::

    udd5, udd6, vdd   <root>/{train,val}/src/<name>.JPG|png and <root>/{train,val}/gt/<name>.png
                      (VDD also test/); index masks of the dataset's ids
    aeroscapes        <root>/JPEGImages/<stem>.jpg, <root>/SegmentationClass/<stem>.png (ids),
                      <root>/ImageSets/{trn,val}.txt (stems)
    icg               <root>/training_set/images/<stem>.jpg,
                      <root>/training_set/gt/semantic/label_images/<stem>.png (colour masks),
                      class_dict.csv (at the root or beside label_images/); labelled: 400
                      training images, no val split

``split``: ``train``, ``val`` (``test`` for VDD) or ``all`` (every labelled split). The masks
hold each dataset's own ids or colours; a palette with a real side for the dataset (``syndrone``)
maps them onto its classes, a dataset's own palette (``udd6``, ``vdd``, ``aeroscapes``) reads
them as its ids. ``RealSegmentation`` yields samples as ``FolderSegmentation`` does.
"""

from __future__ import annotations

import csv
from pathlib import Path

import torch
from matplotlib.figure import Figure
from torch.utils.data import Dataset

from claravid.data import masks
from claravid.data.palettes import Palette, available_palettes, load_palette
from claravid.data.plot import plot_sample
from claravid.data.real_classes import NATIVE
from claravid.data.samples import Sample, Transform, finish_sample, image_tensor
from claravid.data.targets import _check_same_size, index_folder
from claravid.infra.errors import DatasetNotFoundError
from claravid.io import modalities

#: The real datasets read by layout here (UAVid has ``UAVidSegmentation``).
LAYOUT_DATASETS = ("udd5", "udd6", "vdd", "aeroscapes", "icg")
#: The labelled splits of each; ``all`` is their union.
SPLITS: dict[str, tuple[str, ...]] = {
    "udd5": ("train", "val"),
    "udd6": ("train", "val"),
    "vdd": ("train", "val", "test"),
    "aeroscapes": ("train", "val"),
    "icg": ("train",),
}
_AEROSCAPES_LISTS = {"train": "trn.txt", "val": "val.txt"}
_ICG = Path("training_set")


def default_palette(dataset: str) -> str:
    """The dataset's own palette where one is shipped, else ``syndrone``."""
    return dataset if dataset in available_palettes() else "syndrone"


def _src_gt(root: Path, dataset: str, split: str) -> list[tuple[Path, Path]]:
    title = NATIVE[dataset].title
    images = index_folder(root / split / "src", f"{title} {split} images")
    labels = index_folder(root / split / "gt", f"{title} {split} masks")
    return _pair(images, labels, root / split / "gt")


def _pair(images: dict[str, Path], labels: dict[str, Path], where: Path) -> list[tuple[Path, Path]]:
    missing = [images[k] for k in images if k not in labels]
    if missing:
        raise FileNotFoundError(
            f"{len(missing)} image(s) have no mask in {where}, e.g. {missing[0]}; restore them"
        )
    return [(images[k], labels[k]) for k in images]


def _aeroscapes(root: Path, split: str) -> list[tuple[Path, Path]]:
    listing = root / "ImageSets" / _AEROSCAPES_LISTS[split]
    if not listing.is_file():
        raise DatasetNotFoundError(f"AeroScapes {split} list", listing)
    images = index_folder(root / "JPEGImages", "AeroScapes images")
    labels = index_folder(root / "SegmentationClass", "AeroScapes masks")
    stems = [line.strip() for line in listing.read_text().splitlines() if line.strip()]
    unknown = [s for s in stems if s not in images]
    if unknown:
        raise FileNotFoundError(
            f"{listing} lists {len(unknown)} image(s) not in {root / 'JPEGImages'}, e.g. "
            f"{unknown[0]}; restore them or use the list of this copy"
        )
    return _pair({s: images[s] for s in stems}, labels, root / "SegmentationClass")


def _icg_class_dict(root: Path) -> Path | None:
    for path in (root / "class_dict.csv", root / _ICG / "gt" / "semantic" / "class_dict.csv"):
        if path.is_file():
            return path
    return None


def check_icg_class_dict(path: Path) -> None:
    """Stop when the copy's ``class_dict.csv`` gives a class another colour than the published
    table (the masks would be decoded wrongly), or lists a colour twice.

    Raises:
        ValueError: names the file, the row and both colours.
    """
    table = {c.name: c.color for c in NATIVE["icg"].classes}
    seen: dict[tuple[int, ...], str] = {}
    with path.open(newline="") as handle:
        for number, row in enumerate(csv.DictReader(handle, skipinitialspace=True), 2):
            name = (row.get("name") or "").strip()
            try:
                color = tuple(int(row[k]) for k in ("r", "g", "b"))
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"{path} line {number}: expected name,r,g,b") from None
            if color in seen:
                raise ValueError(
                    f"{path} line {number}: colour {list(color)} listed twice ({seen[color]} "
                    f"and {name}); one colour is one class"
                )
            seen[color] = name
            published_color = table.get(name)
            if published_color != color:
                published = list(published_color) if published_color else "no such class"
                raise ValueError(
                    f"{path} line {number}: {name} is {list(color)}, the Semantic Drone "
                    f"Dataset publishes {published}; this is not its class_dict.csv"
                )


def _icg(root: Path) -> list[tuple[Path, Path]]:
    class_dict = _icg_class_dict(root)
    if class_dict is not None:
        check_icg_class_dict(class_dict)
    images = index_folder(root / _ICG / "images", "ICG training images")
    label_root = root / _ICG / "gt" / "semantic" / "label_images"
    return _pair(images, index_folder(label_root, "ICG label images"), label_root)


def list_pairs(root: str | Path, dataset: str, split: str) -> list[tuple[Path, Path]]:
    """(image, mask) files of a real dataset's split, in a stable order.

    Raises:
        ValueError: an unknown dataset or a split it does not have (named with the ones it has).
        DatasetNotFoundError, FileNotFoundError: the layout is not there; the message names
            the missing folder or file.
    """
    if dataset not in LAYOUT_DATASETS:
        raise ValueError(
            f"unknown real dataset {dataset!r}; use one of {', '.join(LAYOUT_DATASETS)}"
        )
    splits = SPLITS[dataset]
    if split != "all" and split not in splits:
        raise ValueError(
            f"{NATIVE[dataset].title} has no labelled {split!r} split; use "
            f"{', '.join((*splits, 'all'))}"
        )
    root = Path(root).expanduser()
    if not root.is_dir():
        raise DatasetNotFoundError(f"{NATIVE[dataset].title} root", root)
    if dataset == "icg":
        return _icg(root)
    wanted = splits if split == "all" else (split,)
    if dataset == "aeroscapes":
        pairs = [p for s in wanted for p in _aeroscapes(root, s)]
        return list(dict.fromkeys(pairs))  # a stem listed in trn and val counts once
    if split == "all":  # every split that is there (VDD's test may be withheld)
        wanted = tuple(s for s in splits if (root / s / "gt").is_dir()) or splits
    return [p for s in wanted for p in _src_gt(root, dataset, s)]


class RealSegmentation(Dataset):
    """Images and masks of one split of UDD5, UDD6, VDD, AeroScapes or ICG.

    Args:
        root: the dataset's root (see the module docstring for each layout).
        dataset: ``udd5``, ``udd6``, ``vdd``, ``aeroscapes`` or ``icg``.
        split: ``train``, ``val`` (``test`` for VDD) or ``all``.
        palette: the palette to decode the masks onto: one whose real side covers the dataset
            (``syndrone``), or the dataset's own (``udd6``...); None: the dataset's own if the
            toolkit ships one, else ``syndrone``.
        transforms: called on each sample dict.
        mask_dtype: as ``FolderSegmentation``'s.

    Raises:
        PaletteError: the palette cannot decode this dataset's masks.
    """

    def __init__(
        self,
        root: str | Path,
        dataset: str,
        split: str = "train",
        palette: str | Path | Palette | None = None,
        transforms: Transform | None = None,
        mask_dtype: torch.dtype | None = None,
    ) -> None:
        self.root = Path(root).expanduser()
        self.dataset = dataset
        self.split = split
        self.palette = load_palette(palette if palette is not None else default_palette(dataset))
        masks.real_decoder(self.palette, dataset)  # a palette that cannot read it fails now
        self.transforms = transforms
        self.mask_dtype = mask_dtype
        pairs = list_pairs(self.root, dataset, split)
        self.images = [image for image, _ in pairs]
        self.masks = [mask for _, mask in pairs]

    @property
    def classes(self) -> tuple[str, ...]:
        """Class names in train-id order."""
        return self.palette.names

    def read_mask(self, index: int) -> torch.Tensor:
        """The labels of image ``index`` as uint8 train ids of the palette (image not read)."""
        return torch.from_numpy(masks.read_mask(self.masks[index], self.palette, self.dataset))

    def __len__(self) -> int:
        return len(self.images)

    def __getitem__(self, index: int) -> Sample:
        path = self.images[index]
        image = modalities.read_rgb(path)
        sample: Sample = {
            "image": image_tensor(image),
            "path": str(path),
            "key": path.relative_to(self.root).with_suffix("").as_posix(),
        }
        mask = self.read_mask(index)
        _check_same_size(image, mask, path, self.masks[index])
        sample["mask"] = mask
        return finish_sample(sample, self.transforms, self.mask_dtype)

    def plot(self, sample: Sample, show_titles: bool = True, suptitle: str | None = None) -> Figure:
        """Image, mask in palette colours, and ``sample["prediction"]`` if any."""
        return plot_sample(sample, self.palette, show_titles=show_titles, suptitle=suptitle)
