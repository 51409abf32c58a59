"""``claravid-predict --raster``: the flags and the loop over rasters (GeoTIFF, COG, any GDAL
raster), each streamed into ``OUT/<name>.tif`` by
:func:`claravid.eval.inference.raster_job.predict_raster`."""

from __future__ import annotations

import argparse
import math
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from claravid.infra.cli import UsageError

#: What a folder given with --raster is searched for.
RASTER_EXTENSIONS = (".tif", ".tiff")


def _typed(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type whose ValueError message reaches the user (argparse prints its own)."""

    def convert(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    convert.__name__ = parse.__name__
    return convert


def parse_gsd(text: str) -> str | float:
    """``auto`` or metres per pixel > 0."""
    if text == "auto":
        return text
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"--gsd takes 'auto' or metres per pixel > 0 (e.g. 0.05), got {text!r}")
    return value


def add_raster_flags(parser: argparse.ArgumentParser) -> None:
    """``--raster``, ``--bands``, ``--value-range``, ``--gsd``, ``--confidence``."""
    from claravid.io.raster import parse_bands, parse_value_range

    geo = parser.add_argument_group(
        "rasters (GeoTIFF, COG, any GDAL raster, streamed; needs claravid-toolkit[geo])"
    )
    geo.add_argument(
        "--raster", action="store_true",
        help="read inputs through rasterio, window by window, and write OUT/<name>.tif: a COG "
        "class map on the input's grid (CRS, transform, nodata)",
    )  # fmt: skip
    geo.add_argument(
        "--bands", type=_typed(parse_bands), metavar="R,G,B",
        help="band numbers (from 1) read as red, green, blue (default: 1,2,3 of an RGB or RGBA "
        "raster)",
    )  # fmt: skip
    geo.add_argument(
        "--value-range", type=_typed(parse_value_range), metavar="LOW,HIGH",
        help="sample values mapped to 0 and 255 (required for uint16 and other non-uint8 samples)",
    )  # fmt: skip
    geo.add_argument(
        "--gsd", type=_typed(parse_gsd), metavar="auto|METRES",
        help="match the model's ground sampling distance: 'auto' reads a raster's from its "
        "projected CRS; a number states the data's metres per pixel",
    )  # fmt: skip
    geo.add_argument(
        "--confidence", action="store_true",
        help="with --raster: band 2, the winning probability x 254 (255: nodata)",
    )  # fmt: skip


def check_raster_flags(args: argparse.Namespace) -> None:
    """Refuse raster-only flags without ``--raster`` (and ``--gsd auto`` on images), and
    test-time augmentation with it (a raster is streamed in one copy)."""
    if args.raster:
        augment = {"tta": args.tta not in (None, "none"), "tta_scales": bool(args.tta_scales),
                   "flip": args.flip, "tta_size": args.tta_size is not None}  # fmt: skip
        given = [name for name, on in augment.items() if on]
        if given:
            flags = ", ".join("--" + name.replace("_", "-") for name in given)
            raise UsageError(f"{flags} do not apply to --raster: a raster is streamed window by "
                             "window in one copy; drop them")  # fmt: skip
        return
    given = [name for name in ("bands", "value_range", "confidence") if getattr(args, name)]
    if given:
        flags = ", ".join("--" + name.replace("_", "-") for name in given)
        raise UsageError(f"{flags} apply to rasters: add --raster")
    if args.gsd == "auto":
        raise UsageError("--gsd auto reads a raster's georeference: add --raster, or state the "
                         "images' metres per pixel (--gsd 0.05)")  # fmt: skip


def list_rasters(inputs: list[Path]) -> tuple[list[Path], list[str]]:
    """Raster files and their output names: one folder's ``.tif``/``.tiff`` (recursive), or the
    listed files (any GDAL format)."""
    from claravid.eval.inputs.label_maps import image_key

    if len(inputs) == 1 and inputs[0].is_dir():
        root = inputs[0]
        paths = sorted(
            p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in RASTER_EXTENSIONS
        )
        if not paths:
            raise UsageError(f"no rasters ({', '.join(RASTER_EXTENSIONS)}) under {root}")
        return paths, [image_key(p, root) for p in paths]
    for p in inputs:
        if not p.is_file():
            raise UsageError(f"{p} is not a raster file (give one folder or raster files)")
    keys = [image_key(p) for p in inputs]
    if len(set(keys)) < len(keys):
        raise UsageError("two listed rasters share a file name; give their folder instead")
    return list(inputs), keys


def check_rasters(args: argparse.Namespace) -> tuple[list[Path], list[str]]:
    """The rasters of ``args.images`` and their output names, each opened and checked (bands,
    samples, value range) before any model work.

    Raises:
        RasterError: rasterio missing, or a raster the flags cannot read (one line).
    """
    from claravid.io.raster import NoCrsWarning, RasterReader, require_rasterio

    require_rasterio()  # one line naming the extra
    paths, keys = list_rasters(args.images)
    for path in paths:
        with warnings.catch_warnings():  # said once, when the raster is predicted
            warnings.simplefilter("ignore", NoCrsWarning)
            RasterReader(path, args.bands, args.value_range).close()
    return paths, keys


def run_rasters(
    args: argparse.Namespace,
    rasters: tuple[list[Path], list[str]],
    source: Any,
    settings: Any,
    colors: np.ndarray,
    out: Path,
) -> list[Any]:
    """Predict ``rasters`` (from :func:`check_rasters`) into ``out/<name>.tif``; the results."""
    from claravid.eval.inference.raster_job import predict_raster

    paths, keys = rasters
    results = []
    for path, key in zip(paths, keys, strict=True):
        target = out / f"{key}.tif"
        if target.resolve() == path.resolve():
            raise UsageError(f"{target} would replace its own input; choose another --output")
        target.parent.mkdir(parents=True, exist_ok=True)
        options = {"bands": args.bands, "value_range": args.value_range, "gsd": args.gsd,
                   "model_gsd": source.defaults.get("gsd"), "confidence": args.confidence,
                   "progress": not args.no_progress}  # fmt: skip
        results.append(
            predict_raster(source.model, path, target, settings.window, colors, **options)
        )
    return results
