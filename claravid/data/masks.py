"""Label images of real datasets, decoded to a palette's train ids with unknown values counted.

Two encodings, told apart by the file itself:

- an *index mask* (one channel, 8 or 16 bits, or a palette-mode PNG whose indices are the
  ids, as VOC-style ``SegmentationClass`` files): values ``0..K-1`` are the palette's train
  ids, 255 is ignore, anything else becomes 255 and is counted;
- a *colour mask* (three channels, 8 bits): colours are matched exactly against the
  palette's class colours; any other colour becomes 255 and is counted.

A palette with a real side (``real:``, e.g. ``syndrone``) decodes a named real dataset's masks
through that side instead: the dataset's own ids or colours, many-to-one onto the palette
(:class:`claravid.data.real_classes.RealMap`).

JPEG masks are refused: compression changes label values along every edge.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np

from claravid.data.palettes import (
    Palette,
    PaletteError,
    available_palettes,
    color_indices,
    load_palette,
)
from claravid.data.real_classes import NATIVE, RealMap
from claravid.infra.errors import CorruptFileError
from claravid.io.modalities import decode_bytes, describe_bytes, png_header, read_checked

_PALETTE_COLOR_TYPE = 3
FIT_FILES = 3  # label files sampled by check_palette_fit
FIT_MAX_UNKNOWN = 0.5  # more label pixels than this outside the palette: the wrong palette
# A real dataset's masks hold its exact ids or colours: more unknown pixels than this, the
# wrong dataset (AeroScapes read as VDD leaves ~40 % unknown, not a majority).
REAL_MAX_UNKNOWN = 0.05
UDD_FILES = 6  # label files sampled to tell UDD5 from UDD6


class UnknownLabelWarning(UserWarning):
    """A mask holds ids or colours outside the palette; those pixels were ignored."""


class DatasetMismatchWarning(UserWarning):
    """Label files look like another dataset's than the palette's (UDD5 read as UDD6)."""


def _png_palette(data: np.ndarray) -> np.ndarray | None:
    """The PLTE chunk of a PNG as uint8 N×3 RGB, or None."""
    raw = data.tobytes()
    offset = 8
    while offset + 8 <= len(raw):
        length = int.from_bytes(raw[offset : offset + 4], "big")
        kind = raw[offset + 4 : offset + 8]
        if kind == b"PLTE":
            body = raw[offset + 8 : offset + 8 + length]
            return np.frombuffer(body, dtype=np.uint8).reshape(-1, 3)
        if kind == b"IDAT":
            return None
        offset += 12 + length
    return None


def _palette_indices(image: np.ndarray, data: np.ndarray, path: Path) -> np.ndarray:
    """Recover the indices of a palette PNG from its decoded colours and its PLTE chunk.

    OpenCV expands palette PNGs to colour; the indices are what an index mask means.
    """
    table = _png_palette(data)
    if table is None:
        raise CorruptFileError(path, "palette PNG without a PLTE chunk")
    if len(np.unique(table, axis=0)) != len(table):
        raise CorruptFileError(
            path,
            "palette PNG whose palette repeats a colour, so its indices cannot be recovered; "
            "save the mask as a single-channel (grey) PNG of ids",
        )
    rgb = image[..., 2::-1] if image.ndim == 3 else np.dstack([image] * 3)
    # Every decoded colour is a PLTE entry; 255 (ignore) would only mark a decoder surprise.
    return color_indices(rgb, table, missing=255)


def read_label_image(path: str | Path) -> np.ndarray:
    """A mask file as ids (H×W, uint8 or uint16) or colours (H×W×3 uint8, RGB order).

    Raises:
        FileNotFoundError: the file does not exist.
        CorruptFileError: JPEG data, a truncated or undecodable file, or an unsupported
            layout (16-bit colour); the message names the file and what was expected.
    """
    path = Path(path)
    data = read_checked(path)
    if describe_bytes(data) == "JPEG data":
        raise CorruptFileError(
            path,
            "expected a lossless mask (PNG of ids or palette colours), found JPEG data, whose "
            "compression changes label values at every edge",
        )
    image = decode_bytes(data, path, cv2.IMREAD_UNCHANGED, checked=True)
    header = png_header(data)
    if header is not None and header[1] == _PALETTE_COLOR_TYPE:
        return _palette_indices(image[..., :3] if image.ndim == 3 else image, data, path)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    if image.ndim == 2:
        if image.dtype not in (np.uint8, np.uint16):
            raise CorruptFileError(path, f"expected 8- or 16-bit ids, found {image.dtype} pixels")
        return image
    if image.dtype != np.uint8:
        raise CorruptFileError(path, f"expected an 8-bit colour mask, found {image.dtype} pixels")
    return np.ascontiguousarray(image[..., 2::-1])  # BGR(A) -> RGB


def real_decoder(palette: Palette, dataset: str | None) -> RealMap | None:
    """The real side of ``palette`` that decodes ``dataset``'s masks; None: the masks hold the
    palette's own ids or colours (a dataset's own palette, e.g. ``udd6`` for UDD6).

    Raises:
        PaletteError: ``palette`` cannot decode ``dataset``'s labels (a real side that does
            not cover it, or a shipped palette of another dataset's classes).
    """
    if dataset is None or dataset not in NATIVE:
        return None
    found = palette.real_map(dataset)
    if found is not None:
        return found
    title = NATIVE[dataset].title
    if palette.real:
        raise PaletteError(
            f"palette {palette.name} decodes the labels of {', '.join(palette.datasets)}, not "
            f"{title}'s; add real.{dataset} to it or pick another palette"
        )
    # A shipped palette of other classes would read this dataset's ids as its own. (UAVid
    # labels converted to another palette's ids are read as that palette's, as ever.)
    foreign = palette.name in available_palettes() and palette.name != dataset
    if foreign and dataset != "uavid":
        raise PaletteError(
            f"palette {palette.name} is written in its own classes' ids and colours, not "
            f"{title}'s, so {title}'s ids would be read as other classes; use a palette whose "
            f"real side covers {dataset} (syndrone)"
        )
    return None


def mask_to_ids(
    mask: np.ndarray, palette: Palette, dataset: str | None = None
) -> tuple[np.ndarray, int]:
    """Ids or colours (from :func:`read_label_image`) -> (uint8 train ids, unknown pixels).

    Ignore (255) in an index mask is not counted as unknown. With ``dataset`` (``udd5``,
    ``icg``...) and a palette whose real side covers it, the mask holds that dataset's own
    ids or colours, decoded through the real side.
    """
    decoder = real_decoder(palette, dataset)
    if decoder is not None:
        return decoder.decode(mask)
    ignore = palette.ignore_index
    if mask.ndim == 3:
        ids = palette.ids_from_colors(mask)
        # Palette ids are 0..254, so 255 here means exactly "colour not in the palette".
        return ids, int(np.count_nonzero(ids == ignore))
    known = mask < palette.num_classes
    unknown = int(mask.size - np.count_nonzero(known) - np.count_nonzero(mask == ignore))
    if mask.dtype == np.uint8:
        lut = np.full(256, ignore, dtype=np.uint8)
        lut[: palette.num_classes] = np.arange(palette.num_classes)
        return cv2.LUT(mask, lut), unknown
    return np.where(known, mask, ignore).astype(np.uint8), unknown


def read_mask(path: str | Path, palette: Palette, dataset: str | None = None) -> np.ndarray:
    """Read a mask file as uint8 train ids of ``palette``; unknown values warn with a count.

    ``dataset``: the real dataset the file belongs to (see :func:`mask_to_ids`).
    """
    ids, unknown = mask_to_ids(read_label_image(path), palette, dataset)
    if unknown:
        decoder = real_decoder(palette, dataset)
        what = (
            f"{decoder.table.title}'s classes" if decoder is not None
            else f"the palette {palette.name!r} ({', '.join(palette.names)})"
        )  # fmt: skip
        warnings.warn(
            f"{unknown} pixel(s) of {path} hold ids or colours outside {what}; they are "
            "ignored (255)",
            UnknownLabelWarning,
            stacklevel=2,
        )
    return ids


def _unknown_share(labels: list[np.ndarray], palette: Palette) -> float:
    total = unknown = 0
    for label in labels:
        ids, count = mask_to_ids(label, palette)
        total, unknown = total + ids.size, unknown + count
    return unknown / max(total, 1)


def _sample(label_files: list[Path], count: int) -> list[Path]:
    """Up to ``count`` files spread over the list."""
    step = max(1, len(label_files) // count)
    return label_files[::step][:count]


def _fitting_datasets(labels: list[np.ndarray], but: str) -> list[str]:
    """The real datasets (other than ``but``) whose own ids or colours cover ``labels``."""
    return [
        name
        for name, table in NATIVE.items()
        if name != but
        and RealMap(name, dict.fromkeys(table.names, 255)).unknown_share(labels) < 0.05
    ]


#: Label files a folder must offer before a missing Roof is taken as a sign of UDD5.
FOLDER_EVIDENCE = 3


def check_udd_version(label_files: list[Path], dataset: str, strict: bool = True) -> None:
    """Stop when a UDD6 read sees UDD5's index masks, or a UDD5 read UDD6's.

    UDD5's ids 0..4 mean Vegetation, Building, Road, Vehicle, Other, UDD6's 0..5 Other,
    Facade, Road, Vegetation, Vehicle, Roof: read as the other, four classes of five are wrong
    and no value is unknown. What tells them apart is Roof (id 5), in every urban UDD6 image.

    ``strict=False`` (a folder read with the ``udd6`` palette, whose masks may be anyone's ids
    0..5) warns instead, and only from `FOLDER_EVIDENCE` files or more.

    Raises:
        ValueError: the sampled index masks hold no id 5 (read as ``udd6``) or some (``udd5``).
    """
    files = _sample(label_files, UDD_FILES)
    labels = [read_label_image(f) for f in files]
    if not labels or any(label.ndim == 3 for label in labels):
        return  # colour masks: UDD5 and UDD6 give a colour the same meaning
    top = max((int(label.max()) for label in labels if label.size), default=0)
    message = None
    if dataset == "udd6" and top <= 4:
        message = (
            f"{len(files)} UDD6 label file(s) such as {files[0]} hold only ids 0-4 and no Roof "
            "(5): this is a UDD5 tree, whose ids mean other classes (0 Vegetation, 1 Building, "
            "2 Road, 3 Vehicle, 4 Other); read it as udd5 (--dataset udd5, palette syndrone)"
        )
    if dataset == "udd5" and top == 5:
        message = (
            f"UDD5 label file(s) such as {files[0]} hold id 5, UDD6's Roof: this is a UDD6 "
            "tree, whose ids mean other classes; read it as udd6 (--dataset udd6)"
        )
    if message is not None and strict:
        raise ValueError(message)
    # A folder's few label maps may lack Roof by chance: only a sample of several says so.
    if message is not None and len(files) >= FOLDER_EVIDENCE:
        warnings.warn(message.replace("this is", "this may be"), DatasetMismatchWarning, 2)


def check_palette_fit(
    label_files: list[Path],
    palette: Palette,
    flag: str = "--palette",
    dataset: str | None = None,
) -> None:
    """Stop when most label pixels fall outside ``palette``, naming the palette that fits.

    Reading UAVid's colour labels with the ClaraVid palette ignores ~90 % of the pixels (one
    warning per file) and scores the rest: a number that means nothing. A few files, spread
    over the set, are read once more here, before any work. With ``dataset`` and a palette
    whose real side covers it, the files must hold that dataset's ids or colours, and the
    message names the real datasets whose ids or colours they do hold. UDD5 read as UDD6
    (or back) is told apart by :func:`check_udd_version`.

    Raises:
        ValueError: more than half of the sampled label pixels are outside ``palette`` (or
            the dataset's classes), or a UDD tree of the other version.
    """
    if not label_files:
        return
    files = _sample(label_files, FIT_FILES)
    labels = [read_label_image(f) for f in files]
    decoder = real_decoder(palette, dataset)
    udd = dataset if dataset is not None else palette.name
    if udd in ("udd5", "udd6"):  # a folder read in the udd6 palette: a warning only
        check_udd_version(label_files, udd, strict=dataset is not None)
    if decoder is not None:
        share = decoder.unknown_share(labels)
        if share <= REAL_MAX_UNKNOWN:
            return
        others = _fitting_datasets(labels, decoder.dataset)
        hint = f"they are {' or '.join(others)} labels: pass --dataset {others[0]}" if others else (
            "check the data folder"
        )  # fmt: skip
        raise ValueError(
            f"{share:.0%} of the label pixels of {len(files)} file(s) such as {files[0]} hold "
            f"ids or colours that {decoder.table.title} does not have; {hint}"
        )
    share = _unknown_share(labels, palette)
    if share <= FIT_MAX_UNKNOWN:
        return
    fits = [
        name
        for name in available_palettes()
        if name != palette.name and _unknown_share(labels, load_palette(name)) < 0.05
    ]
    hint = f"they fit palette {' or '.join(fits)}: pass {flag} {fits[0]}" if fits else (
        f"pass {flag} with the palette they are written in"
    )  # fmt: skip
    raise ValueError(
        f"{share:.0%} of the label pixels of {len(files)} file(s) such as {files[0]} hold "
        f"values outside palette {palette.name}; {hint}"
    )
