"""Predict one raster of any size into a Cloud-Optimized GeoTIFF class map.

:func:`predict_raster` ties the pieces together: :class:`claravid.io.raster.RasterReader` reads
bands of rows, :func:`claravid.eval.inference.raster.stream_logits` runs and blends the windows,
:class:`claravid.io.cog.ClassMapWriter` writes the finished rows (class, optional confidence,
nodata where the input has no data) and publishes the COG only when every row is in. A model
that records its ground sampling distance is run at it: ``gsd="auto"`` reads the raster's from
its projected CRS, a number states it, and the raster is resampled while it is read; the class
map keeps the raster's own grid.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from claravid.eval.inference.raster import RowResizer, stream_logits, window_count
from claravid.eval.inference.windows import Model, WindowConfig
from claravid.io.cog import CONFIDENCE_MAX, NODATA, ClassMapWriter
from claravid.io.raster import RasterError, RasterInfo, RasterReader

#: GDAL's block cache (MB) while a raster is predicted. Its default is 5 % of the machine's RAM,
#: which the COG conversion of a large class map fills: peak memory then grows with the machine.
GDAL_CACHE_MB = 256

#: How far a stated --gsd may differ from the raster's own before a warning says so.
GSD_TOLERANCE = 0.01


class GsdWarning(UserWarning):
    """A stated GSD differs from the one the raster's georeference gives."""


@dataclass(frozen=True)
class RasterResult:
    """What :func:`predict_raster` did."""

    path: Path
    width: int
    height: int
    windows: int
    scale: tuple[float, float]  # (y, x) resampling of the raster before the windows
    raster_gsd: tuple[float, float] | None  # (x, y) metres per pixel used, None: unknown
    model_gsd: float | None
    seconds: float


def resolve_scale(
    info: RasterInfo, model_gsd: float | None, gsd: str | float | None, scale: float = 1.0
) -> tuple[tuple[float, float], tuple[float, float] | None]:
    """The (y, x) resampling of the raster and its GSD (x, y).

    Args:
        info: the raster.
        model_gsd: metres per pixel of the model's training images (None: not recorded).
        gsd: None (run at ``scale``), ``"auto"`` (the raster's GSD from its projected CRS), or
            the raster's GSD in metres per pixel.
        scale: the window config's scale, used when ``gsd`` is None.

    Raises:
        RasterError: a GSD match asked of a model without a GSD, or of a raster without a
            projected CRS and no stated GSD.
    """
    own = info.gsd()
    if gsd is None:
        return (scale, scale), own
    if model_gsd is None:
        raise RasterError(
            "the model records no ground sampling distance (trained on data without one: set "
            "data.gsd when training), so --gsd cannot match it; drop --gsd (and use --scale)"
        )
    if gsd == "auto":
        if own is None:
            crs = "no CRS" if info.crs is None else f"a CRS in {_unit(info.crs)}"
            raise RasterError(
                f"{info.path} has {crs}, so its GSD is unknown: state it with --gsd METRES "
                "(metres per pixel, e.g. --gsd 0.05)"
            )
        raster = own
    else:
        value = float(gsd)
        if own is not None and abs(own[0] - value) > GSD_TOLERANCE * own[0]:
            warnings.warn(
                f"--gsd {value:g} differs from the {own[0]:.4g} m/px of {info.path}'s "
                "georeference; using --gsd",
                GsdWarning,
                stacklevel=2,
            )
        raster = (value, value)
    return (raster[1] / model_gsd, raster[0] / model_gsd), raster


def _unit(crs: Any) -> str:
    return "degrees (geographic)" if crs.is_geographic else "units GDAL cannot convert to metres"


def raster_logits(
    model: Model,
    reader: RasterReader,
    config: WindowConfig,
    scale: tuple[float, float],
    progress: Any = None,
) -> Iterator[tuple[int, torch.Tensor]]:
    """Averaged window logits of the raster on its own grid, in bands of rows (see
    :func:`~claravid.eval.inference.raster.stream_logits`), the raster resampled by ``scale``
    (y, x) while it is read and the logits resized back."""
    info = reader.info
    height, width = scaled_size(info, scale)
    config = dataclasses.replace(config, scale=1.0)
    if (height, width) == (info.height, info.width):

        def read(top: int, n: int) -> torch.Tensor:
            return torch.from_numpy(reader.read_rows(top, n))

        yield from stream_logits(model, read, height, width, config, progress)
        return
    step = info.height / height  # source rows per resampled row

    def read_scaled(top: int, n: int) -> torch.Tensor:
        return torch.from_numpy(reader.read_rows(top * step, n * step, out_shape=(n, width)))

    resizer = RowResizer((height, width), (info.height, info.width))
    for top, logits in stream_logits(model, read_scaled, height, width, config, progress):
        yield from resizer.push(top, logits)


def scaled_size(info: RasterInfo, scale: tuple[float, float]) -> tuple[int, int]:
    """(height, width) of the raster resampled by ``scale`` (y, x)."""
    if not all(math.isfinite(s) and 0 < s <= 8 for s in scale):
        raise RasterError(f"resampling the raster by {scale[1]:.3g} x {scale[0]:.3g} is outside "
                          "(0, 8]: check --gsd and --scale")  # fmt: skip
    return max(1, round(info.height * scale[0])), max(1, round(info.width * scale[1]))


def predict_raster(
    model: Model,
    source: str | Path,
    output: str | Path,
    config: WindowConfig,
    colors: np.ndarray,
    *,
    bands: tuple[int, int, int] | None = None,
    value_range: tuple[float, float] | None = None,
    gsd: str | float | None = None,
    model_gsd: float | None = None,
    confidence: bool = False,
    progress: bool = True,
) -> RasterResult:
    """Predict ``source`` into the COG ``output`` (written last, atomically).

    Args:
        model: maps [B,3,h,w] to [B,K,h,w] logits.
        source: a raster GDAL reads.
        output: the class map to write (its folder must exist).
        config: the windows (resolved for the model: `WindowConfig.for_model`).
        colors: K × 3 palette colours (the band's colour table).
        bands, value_range: how samples become RGB (`claravid.io.raster.RasterReader`).
        gsd, model_gsd: see :func:`resolve_scale`.
        confidence: add band 2, the winning probability × 254.
        progress: show a progress bar over the windows.

    Raises:
        RasterError: an unusable raster or GSD; RasterReadError: a window failed to read
            (nothing is left in the output folder).
    """
    start = time.perf_counter()
    config = config.for_model(model)
    if len(colors) > NODATA:
        raise RasterError(f"{len(colors)} classes do not fit a uint8 map beside nodata {NODATA}")
    with _gdal_cache(), RasterReader(source, bands, value_range) as reader:
        info = reader.info
        scale, raster_gsd = resolve_scale(info, model_gsd, gsd, config.scale)
        windows = window_count(*scaled_size(info, scale), config)
        bar = tqdm(total=windows, unit="window", desc=Path(source).name, disable=not progress)
        writer = ClassMapWriter(output, info, colors, confidence)
        try:
            for top, logits in raster_logits(model, reader, config, scale, bar.update):
                write_band(writer, reader, top, logits, confidence)
            path = writer.close()
        except BaseException:
            writer.abort()
            raise
        finally:
            bar.close()
    return RasterResult(path, info.width, info.height, windows, scale, raster_gsd, model_gsd,
                        time.perf_counter() - start)  # fmt: skip


def _gdal_cache() -> Any:
    from claravid.io.raster import require_rasterio

    return require_rasterio().Env(GDAL_CACHEMAX=GDAL_CACHE_MB)


def write_band(
    writer: ClassMapWriter, reader: RasterReader, top: int, logits: torch.Tensor, confidence: bool
) -> None:
    """Classes and confidence of rows ``top..``, nodata where the input has none."""
    valid = reader.read_mask(top, logits.shape[1])
    labels, best = classes(logits)
    labels[~valid] = NODATA
    conf = None
    if confidence:
        # The winning class's softmax probability: 1 / sum_k exp(logit_k - max).
        total = torch.zeros_like(best)
        for plane in logits:
            total += torch.exp(plane - best)
        conf = torch.round(CONFIDENCE_MAX / total).to(torch.uint8).numpy()
        conf[~valid] = NODATA
    writer.write_rows(labels, conf)


def classes(logits: torch.Tensor) -> tuple[np.ndarray, torch.Tensor]:
    """uint8 argmax over the classes of [K, h, w] logits (the first of equal maxima, as
    ``argmax``) and the maxima; one pass per class over contiguous planes (``argmax(0)``
    strides across them, several times slower)."""
    best = logits[0].clone()
    labels = torch.zeros(best.shape, dtype=torch.uint8)
    for k in range(1, logits.shape[0]):
        labels.masked_fill_(logits[k] > best, k)
        torch.maximum(best, logits[k], out=best)
    return labels.numpy(), best
