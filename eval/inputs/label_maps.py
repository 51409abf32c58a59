"""Label maps on disk: the ``--predictions`` / ``--save-predictions`` format, and scoring them.

Format: one single-channel 8-bit PNG of palette train ids per image, at ``DIR/<key>.png`` (an
8-bit palette-mode PNG whose indices are the ids is read too);
for ClaraVid the key is ``<mission folder>/<altitude>_<direction>/<stem>``, for UAVid and
folders the image's path relative to the data root without its extension. Any model can be
evaluated this way: write its label maps in this layout.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from claravid.data.masks import read_label_image
from claravid.data.palette_fold import PaletteFold, is_fine
from claravid.data.palettes import Palette, load_palette
from claravid.eval.measures.confusion import image_confusion
from claravid.infra.cli import UsageError
from claravid.infra.files import atomic_save, atomic_write_text
from claravid.io import modalities

SHOW_MISSING = 5
#: What a folder of label maps written by claravid-eval/claravid-predict holds besides them: its
#: presence marks the folder as ours (rewritable without --overwrite).
MARKER = "predictions.json"
PALETTE_PNG = 3  # the PNG colour type of an indexed (palette-mode) image


class PredictionError(ValueError):
    """A prediction file is unusable; the message names it and says what is expected."""


def image_key(path: str | Path, root: str | Path | None = None) -> str:
    """The name an image's label map is saved under: its path relative to ``root`` without the
    extension (``seq1/Images/000000``), or its stem when there is no root or it lies elsewhere.

    ClaraVid frames carry their own key (``<mission folder>/<viewpoint>/<stem>``, the frame's
    path relative to the dataset root), which is this rule applied to the ClaraVid root.
    """
    path = Path(path)
    if root is not None:
        try:
            return path.resolve().relative_to(Path(root).resolve()).with_suffix("").as_posix()
        except ValueError:
            pass
    return path.stem


def prediction_file(directory: str | Path, key: str) -> Path:
    """Where the prediction of the image named ``key`` lives."""
    return Path(directory) / f"{key}.png"


def write_prediction(directory: str | Path, key: str, ids: np.ndarray) -> Path:
    """Write train ids (uint8 H×W) as ``DIR/<key>.png``, atomically (temp file + rename)."""
    path = prediction_file(directory, key)
    ids = np.asarray(ids)
    if ids.ndim != 2 or ids.dtype != np.uint8:
        raise ValueError(f"a prediction is uint8 [H,W], got {ids.dtype} {ids.shape}")
    # Level 1: label maps compress well anyway, and it keeps saving off the critical path.
    return write_image(path, ids, [cv2.IMWRITE_PNG_COMPRESSION, 1])


def write_image(path: Path, image: np.ndarray, params: list[int]) -> Path:
    """``cv2.imwrite`` atomically (temp file + rename), raising when OpenCV cannot write."""

    def write(tmp: Path) -> None:
        if not cv2.imwrite(str(tmp), image, params):
            raise OSError(f"cannot write {path}")

    return atomic_save(path, write)


def write_marker(
    directory: str | Path, palette: Palette | None, source: dict[str, Any], **extra: Any
) -> Path:
    """Write ``DIR/predictions.json``: the format, the palette its ids refer to, the source."""
    marker = {
        "format": "claravid-predictions",
        "palette": palette.name if palette is not None else None,
        "classes": list(palette.names) if palette is not None else None,
        "source": source,
        **extra,
    }
    return atomic_write_text(Path(directory) / MARKER, json.dumps(marker, indent=2))


def predictions_defaults(
    directory: str | Path, palette: str | Path | None = None
) -> dict[str, Any]:
    """What a folder of label maps says about evaluating it: the palette of its ids.

    The palette comes from ``DIR/predictions.json`` (written by ``--save-predictions`` and
    claravid-predict); a ``palette`` given by the user must agree with it, unless the label
    maps hold ClaraVid's 19 classes: then they are scored through ``palette``
    (``model_classes`` in the answer names their classes).

    Raises:
        UsageError: the folder does not exist, ``palette`` contradicts the marker, or neither
            the marker nor ``palette`` names the palette.
    """
    directory = Path(directory)
    if not directory.exists():
        raise UsageError(f"--predictions {directory}: folder not found")
    if not directory.is_dir():
        raise UsageError(f"--predictions {directory} is a file; give the folder of label maps")
    try:
        marker = json.loads((directory / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):  # no marker (label maps of another program): nothing known
        marker = None
    written = marker.get("palette") if isinstance(marker, dict) else None
    if not isinstance(written, str):
        if palette is None:  # a default palette would score another palette's ids silently
            raise UsageError(
                f"--predictions {directory} has no {MARKER} saying which palette its ids "
                "belong to: pass --palette (e.g. --palette uavid)"
            )
        return {}
    if palette is not None:
        classes = marker.get("classes")
        given = load_palette(palette)
        same = list(given.names) == classes if isinstance(classes, list) else given.name == written
        if not same and isinstance(classes, list) and is_fine(classes):
            # A fine model's label maps, scored through the given palette's ClaraVid side.
            return {"palette": str(palette), "model_classes": list(classes)}
        if not same:
            raise UsageError(
                f"--palette {palette} contradicts {directory / MARKER}: these label maps hold "
                f"ids of palette {written}; drop --palette (only label maps of ClaraVid's "
                "19 classes are scored through another palette)"
            )
    return {"palette": written}


def read_prediction(path: str | Path, shape: tuple[int, int], num_classes: int) -> np.ndarray:
    """Read and check one prediction: uint8 [H,W] of ids in ``[0, num_classes)``.

    Decoded through the data layer's reader, so an empty or truncated file, or JPEG bytes under
    a ``.png`` name (lossy: ids change along every edge), is refused instead of half-read.

    Raises:
        PredictionError: unreadable, not a single-channel 8-bit PNG, of the wrong size, or
            holding ids outside the palette; the message names the file.
        CorruptFileError: an empty or truncated file (the message names it).
    """
    path = Path(path)
    data = modalities.read_checked(path)
    header = modalities.png_header(data)
    if header is None:
        raise PredictionError(
            f"prediction {path} holds {modalities.describe_bytes(data)}; expected a "
            "single-channel 8-bit PNG of train ids"
        )
    if header == (8, PALETTE_PNG):
        # A palette-mode PNG (VOC style): its indices are the ids, read as masks read them.
        ids = read_label_image(path)
    else:
        ids = modalities.decode_bytes(data, path, cv2.IMREAD_UNCHANGED)
    if ids.ndim != 2:
        raise PredictionError(
            f"prediction {path} has {ids.shape[2]} channels; expected a single-channel PNG of "
            "train ids (not a colour overlay)"
        )
    if ids.dtype != np.uint8:
        raise PredictionError(
            f"prediction {path} holds {ids.dtype} pixels; expected 8-bit train ids (uint8)"
        )
    if ids.shape != tuple(shape):
        raise PredictionError(
            f"prediction {path} is {ids.shape[1]}×{ids.shape[0]} but its image is "
            f"{shape[1]}×{shape[0]}; predictions must be at the labels' native resolution"
        )
    top = int(ids.max()) if ids.size else 0
    if top >= num_classes:
        bad = np.unique(ids[ids >= num_classes])[:8].tolist()
        raise PredictionError(
            f"prediction {path} holds ids {bad} outside the palette's {num_classes} classes "
            f"(0..{num_classes - 1})"
        )
    return ids


def read_scored(
    path: str | Path, shape: tuple[int, int], num_classes: int, fold: PaletteFold | None = None
) -> np.ndarray:
    """:func:`read_prediction` of ids in the palette scored on: with a ``fold``, the file holds
    a fine model's ids (checked against its 19 classes), mapped onto the palette
    (:meth:`PaletteFold.label_table`)."""
    if fold is None:
        return read_prediction(path, shape, num_classes)
    return cv2.LUT(read_prediction(path, shape, fold.num_source), fold.label_table())


def find_missing(directory: str | Path, keys: Sequence[str], indices: Iterable[int]) -> list[int]:
    """The indices whose prediction file does not exist."""
    return [i for i in indices if not prediction_file(directory, keys[i]).is_file()]


class LabeledImages(Protocol):
    """What scoring saved label maps reads of the evaluated images (an
    :class:`~claravid.eval.inputs.datasets.EvalData`, which names its images by
    :func:`image_key`): their keys, palette and labels."""

    keys: list[str]
    palette: Palette

    def __len__(self) -> int: ...

    def read_mask(self, index: int) -> np.ndarray:
        """The train ids (uint8 H×W) of image ``index``."""
        ...


def missing_message(directory: str | Path, keys: Sequence[str], missing: Sequence[int]) -> str:
    """``N prediction(s) missing in DIR, e.g. a.png, b.png``: what the error and warning say."""
    shown = ", ".join(str(prediction_file(directory, keys[i])) for i in missing[:SHOW_MISSING])
    more = ", …" if len(missing) > SHOW_MISSING else ""
    return f"{len(missing)} prediction(s) missing in {directory}: {shown}{more}"


def check_missing(
    directory: str | Path, data: LabeledImages, allow_missing: bool
) -> tuple[list[int], list[int]]:
    """Split the data's indices into (present, missing) predictions.

    Raises:
        UsageError: predictions are missing and ``allow_missing`` is off, or all are missing.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise UsageError(f"--predictions {directory} is not a folder")
    missing = find_missing(directory, data.keys, range(len(data)))
    present = sorted(set(range(len(data))) - set(missing))
    if missing and (not allow_missing or not present):
        hint = "" if not present else "; pass --allow-missing to evaluate the others"
        layout = prediction_file(directory, data.keys[missing[0]])
        raise UsageError(
            f"{missing_message(directory, data.keys, missing)}{hint} (expected {layout})"
        )
    return present, missing


#: What else is measured of an image from its index, prediction and labels (in the thread
#: that read them): its boundary sums, its pair with the next frame...
Measure = Callable[[int, np.ndarray, np.ndarray], Any]


def _score_one(
    data: LabeledImages,
    directory: Path,
    index: int,
    tile_size: int | None,
    measure: Measure | None,
    fold: PaletteFold | None = None,
) -> tuple[np.ndarray, np.ndarray | None, Any]:
    mask = data.read_mask(index)
    k = data.palette.num_classes
    ids = read_scored(prediction_file(directory, data.keys[index]), mask.shape, k, fold)
    conf, tiles = image_confusion(ids, mask, k, tile_size)
    return conf, tiles, None if measure is None else measure(index, ids, mask)


def label_map_confusions(
    data: LabeledImages,
    directory: str | Path,
    indices: Sequence[int],
    *,
    threads: int = 1,
    tile_size: int | None = None,
    progress: bool = False,
    measure: Measure | None = None,
    fold: PaletteFold | None = None,
) -> list[tuple[np.ndarray, np.ndarray | None, Any]]:
    """Per-image confusions (int64 [K,K]) of saved predictions against the labels, each with
    its tiles' confusions (int64 [rows, cols, K, K]) when ``tile_size`` is given, else None,
    and what ``measure`` returns of the image (None without it).

    Only the labels and the prediction PNGs are decoded. Decoding and counting release the GIL,
    so ``threads`` > 1 reads several images at once. With a ``fold`` the label maps hold a
    fine model's ids, mapped onto the data's palette (:meth:`PaletteFold.label_table`).
    """
    from tqdm.auto import tqdm

    directory = Path(directory)
    bar = tqdm(total=len(indices), desc="evaluate", unit="img", disable=not progress)
    out: list[tuple[np.ndarray, np.ndarray | None, Any]] = []
    try:
        if threads <= 1:
            for index in indices:
                out.append(_score_one(data, directory, index, tile_size, measure, fold))
                bar.update(1)
        else:
            with ThreadPoolExecutor(threads) as pool:
                scored = pool.map(
                    lambda i: _score_one(data, directory, i, tile_size, measure, fold), indices
                )
                for item in scored:
                    out.append(item)
                    bar.update(1)
    finally:
        bar.close()
    return out
