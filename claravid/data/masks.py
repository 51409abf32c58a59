"""Label images of real datasets, decoded to a palette's train ids with unknown values counted.

Two encodings, told apart by the file itself:

- an *index mask* (one channel, 8 or 16 bits, or a palette-mode PNG whose indices are the
  ids, as VOC-style ``SegmentationClass`` files): values ``0..K-1`` are the palette's train
  ids, 255 is ignore, anything else becomes 255 and is counted;
- a *colour mask* (three channels, 8 bits): colours are matched exactly against the
  palette's class colours; any other colour becomes 255 and is counted.

JPEG masks are refused: compression changes label values along every edge.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np

from claravid.data.palettes import Palette, available_palettes, color_indices, load_palette
from claravid.infra.errors import CorruptFileError
from claravid.io.modalities import decode_bytes, describe_bytes, png_header, read_checked

_PALETTE_COLOR_TYPE = 3
FIT_FILES = 3  # label files sampled by check_palette_fit
FIT_MAX_UNKNOWN = 0.5  # more label pixels than this outside the palette: the wrong palette


class UnknownLabelWarning(UserWarning):
    """A mask holds ids or colours outside the palette; those pixels were ignored."""


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


def mask_to_ids(mask: np.ndarray, palette: Palette) -> tuple[np.ndarray, int]:
    """Ids or colours (from :func:`read_label_image`) -> (uint8 train ids, unknown pixels).

    Ignore (255) in an index mask is not counted as unknown.
    """
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


def read_mask(path: str | Path, palette: Palette) -> np.ndarray:
    """Read a mask file as uint8 train ids of ``palette``; unknown values warn with a count."""
    ids, unknown = mask_to_ids(read_label_image(path), palette)
    if unknown:
        warnings.warn(
            f"{unknown} pixel(s) of {path} hold ids or colours outside the palette "
            f"{palette.name!r} ({', '.join(palette.names)}); they are ignored (255)",
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


def check_palette_fit(label_files: list[Path], palette: Palette, flag: str = "--palette") -> None:
    """Stop when most label pixels fall outside ``palette``, naming the palette that fits.

    Reading UAVid's colour labels with the ClaraVid palette ignores ~90 % of the pixels (one
    warning per file) and scores the rest: a number that means nothing. A few files, spread
    over the set, are read once more here, before any work.

    Raises:
        ValueError: more than half of the sampled label pixels are outside ``palette``.
    """
    if not label_files:
        return
    step = max(1, len(label_files) // FIT_FILES)
    files = label_files[::step][:FIT_FILES]
    labels = [read_label_image(f) for f in files]
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
