"""The ``claravid-export`` console script: `claravid.models.export` plus the data layer.

The export itself lives in ``models/``, which never imports the data layer; but the file it
writes should carry the palette's class names and colours (not only its name) and, for static
int8 quantisation, be calibrated on real images. Both need the data layer, so the console
script is this thin wrapper, downstream of both, that hands ``models.export.main`` a palette
resolver and an image reader.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from claravid.models import export


def palette_info(name: str) -> dict[str, Any] | None:
    """The palette a checkpoint names, as plain data for the ONNX metadata (None: unreadable)."""
    from claravid.palettes import load_palette

    try:
        palette = load_palette(name)
    except (OSError, ValueError) as exc:
        warnings.warn(f"the ONNX file will not carry the palette: {exc}", UserWarning, stacklevel=2)
        return None
    return {
        "name": palette.name,
        "names": list(palette.names),
        "colors": palette.colors.tolist(),
        "ignore_index": int(palette.ignore_index),
    }


def calibration_batches(
    folder: str | Path,
    count: int,
    size: tuple[int, int],
    normalisation: dict[str, Any],
    seed: int = 0,
) -> Iterator[np.ndarray]:
    """``count`` random crops of ``size`` from the images under ``folder``, one per batch.

    A ClaraVid root gives its RGB frames (``left_rgb``) only, not the label images. Images are
    taken in a seeded random order, cycling when there are fewer images than crops; an image
    smaller than the crop is padded with the mean colour (0 after normalisation).
    """
    from claravid import modalities
    from claravid.eval.predict import list_images

    paths, _ = list_images([Path(folder)])
    rgb = [p for p in paths if "left_rgb" in p.parts]
    paths = rgb or paths
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(paths))
    mean = np.asarray(normalisation["mean"], np.float32).reshape(3, 1, 1)
    std = np.asarray(normalisation["std"], np.float32).reshape(3, 1, 1)
    h, w = size
    for i in range(count):
        image = modalities.read_rgb(paths[order[i % len(paths)]])
        y = int(rng.integers(0, max(1, image.shape[0] - h + 1)))
        x = int(rng.integers(0, max(1, image.shape[1] - w + 1)))
        crop = image[y : y + h, x : x + w].transpose(2, 0, 1).astype(np.float32)
        out = np.zeros((1, 3, h, w), np.float32)
        out[0, :, : crop.shape[1], : crop.shape[2]] = (crop / 255 - mean) / std
        yield out


def main(argv: list[str] | None = None) -> int:
    """``claravid-export`` (see `claravid.models.export`)."""
    return export.main(argv, resolve_palette=palette_info, read_calibration=calibration_batches)


if __name__ == "__main__":
    raise SystemExit(main())
