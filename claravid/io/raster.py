"""Rasters larger than memory (GeoTIFF, COG, anything GDAL reads), read a band of rows at a time.

rasterio (the optional extra ``claravid-toolkit[geo]``; its wheels bundle GDAL) does the format
work: windowed reads, the valid-data mask (nodata values, internal masks and an alpha band all
fold into ``dataset_mask``), the georeference. This module turns a raster into what the models
take: uint8 RGB rows, in the band order ``bands`` names, with samples of other types mapped
linearly from a stated ``value_range`` to 0..255.

Every way a raster can be unusable is a :class:`RasterError` (a ``ValueError``: one line for the
command line, exit 2), raised when the raster is opened, before any work; a block that fails to
decode mid-way is a :class:`RasterReadError` naming the rows and columns it was reading.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: What to install when rasterio is missing.
EXTRA = "pip install 'claravid-toolkit[geo]'"


class RasterError(ValueError):
    """A raster that cannot be used as given; the message says what to pass instead."""


class RasterReadError(RasterError):
    """A window of the raster failed to read (a corrupt block, a truncated file)."""


class NoCrsWarning(UserWarning):
    """The raster has no coordinate reference system: its output will have none either."""


def require_rasterio() -> Any:
    """The ``rasterio`` module, or a :class:`RasterError` naming the extra that brings it."""
    try:
        import rasterio
    except ImportError:
        raise RasterError(f"reading rasters needs rasterio: {EXTRA}") from None
    return rasterio


def parse_bands(text: str) -> tuple[int, int, int]:
    """``"3,2,1"`` → ``(3, 2, 1)``: the 1-based bands read as red, green and blue."""
    try:
        bands = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise RasterError(f"--bands takes three band numbers like 1,2,3, got {text!r}") from None
    if len(bands) != 3 or min(bands) < 1:
        raise RasterError(f"--bands takes three band numbers (from 1) like 3,2,1, got {text!r}")
    return bands[0], bands[1], bands[2]


def parse_value_range(text: str) -> tuple[float, float]:
    """``"0,4095"`` → ``(0.0, 4095.0)``: the sample values mapped to 0 and 255."""
    try:
        low, high = (float(v) for v in text.split(","))
    except ValueError:
        raise RasterError(f"--value-range takes LOW,HIGH like 0,4095, got {text!r}") from None
    if not (math.isfinite(low) and math.isfinite(high) and high > low):
        raise RasterError(f"--value-range needs finite LOW < HIGH, got {text!r}")
    return low, high


@dataclass(frozen=True)
class RasterInfo:
    """What a raster says about itself: size, georeference, samples, the bands read."""

    path: str
    width: int
    height: int
    count: int
    dtype: str
    crs: Any  # rasterio.crs.CRS or None
    transform: Any  # affine.Affine
    nodata: float | None
    bands: tuple[int, int, int]
    value_range: tuple[float, float] | None

    def gsd(self) -> tuple[float, float] | None:
        """Ground sampling distance ``(x, y)`` in metres per pixel, from a projected CRS
        (``|transform.a|``, ``|transform.e|`` in the CRS's linear unit, converted to metres);
        None without a CRS, with a geographic one (degrees), or a rotated grid."""
        if self.crs is None or not self.crs.is_projected:
            return None
        t = self.transform
        if t.b != 0 or t.d != 0:
            return None
        try:
            _, factor = self.crs.linear_units_factor
        except Exception:  # an unnamed unit: GDAL cannot say what it is in metres
            return None
        return abs(t.a) * factor, abs(t.e) * factor


def _default_bands(src: Any) -> tuple[int, int, int]:
    from rasterio.enums import ColorInterp

    count = src.count
    if count == 3:
        return (1, 2, 3)
    if count == 4 and src.colorinterp[3] == ColorInterp.alpha:
        return (1, 2, 3)  # RGBA: the alpha band folds into the valid-data mask
    what = "1 band" if count == 1 else f"{count} bands"
    raise RasterError(
        f"{src.name} has {what}, not RGB or RGBA: pass --bands R,G,B (band numbers from 1"
        + (", e.g. 1,1,1 for a grey image)" if count < 3 else ", e.g. 3,2,1)")
    )


def inspect(src: Any, bands: tuple[int, int, int] | None, value_range: Any) -> RasterInfo:
    """Check an open rasterio dataset against what the models take; warn when it has no CRS.

    Raises:
        RasterError: bands that do not exist or are not given for a raster that is not RGB(A);
            samples other than uint8 without ``value_range``; an empty raster.
    """
    if src.width < 1 or src.height < 1:
        raise RasterError(f"{src.name} is empty ({src.width}x{src.height})")
    chosen = bands or _default_bands(src)
    if max(chosen) > src.count:
        listed = ",".join(map(str, chosen))
        raise RasterError(f"--bands {listed}: {src.name} has {src.count} bands (1..{src.count})")
    dtypes = {src.dtypes[b - 1] for b in chosen}
    dtype = sorted(dtypes)[0] if len(dtypes) == 1 else "mixed"
    if dtype != "uint8" and value_range is None:
        raise RasterError(
            f"{src.name} holds {dtype} samples: pass --value-range LOW,HIGH, the values that "
            f"map to 0 and 255 (e.g. 0,4095 for 12-bit, 0,65535 for the full uint16 range)"
        )
    if src.crs is None:
        warnings.warn(
            f"{src.name} has no CRS: the prediction will have none either",
            NoCrsWarning,
            stacklevel=2,
        )
    return RasterInfo(
        path=str(src.name), width=src.width, height=src.height, count=src.count, dtype=dtype,
        crs=src.crs, transform=src.transform, nodata=src.nodata, bands=chosen,
        value_range=None if value_range is None else tuple(value_range),
    )  # fmt: skip


class RasterReader:
    """A raster open for reading rows: ``with RasterReader(path) as r: r.read_rows(0, 64)``.

    Args:
        path: any raster GDAL opens.
        bands: 1-based bands read as R, G, B (default: 1, 2, 3 of an RGB or RGBA raster).
        value_range: the sample values mapped to 0 and 255 (needed for non-uint8 samples).

    Raises:
        RasterError: rasterio missing, a file GDAL cannot open, or what :func:`inspect` refuses.
    """

    def __init__(
        self,
        path: str | Path,
        bands: tuple[int, int, int] | None = None,
        value_range: tuple[float, float] | None = None,
    ) -> None:
        rasterio = require_rasterio()
        if not Path(path).exists():
            raise RasterError(f"{path} not found")
        try:
            with warnings.catch_warnings():  # said once, by inspect, in our words
                warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                self._src = rasterio.open(path)
        except rasterio.errors.RasterioIOError as exc:
            raise RasterError(f"cannot open {path} as a raster: {_first_line(exc)}") from None
        try:
            self.info = inspect(self._src, bands, value_range)
        except BaseException:
            self._src.close()
            raise

    def __enter__(self) -> RasterReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the dataset."""
        self._src.close()

    def read_rows(
        self, row: float, height: float, out_shape: tuple[int, int] | None = None
    ) -> np.ndarray:
        """uint8 [3, h, W] of rows ``row .. row+height`` (fractional for a resampled read).

        Args:
            row: the first source row (may be fractional with ``out_shape``).
            height: source rows to read (may be fractional with ``out_shape``).
            out_shape: ``(h, w)`` to resample the rows to (GDAL's bilinear); None: as stored.

        Raises:
            RasterReadError: the window failed to decode.
        """
        from rasterio.enums import Resampling
        from rasterio.windows import Window

        info = self.info
        window = Window(0, row, info.width, height)
        shape = None if out_shape is None else (3, *out_shape)
        data = self._read(
            lambda: self._src.read(
                list(info.bands), window=window, out_shape=shape, resampling=Resampling.bilinear
            ),
            window,
        )
        return to_uint8(data, info.value_range)

    def read_mask(self, row: int, height: int) -> np.ndarray:
        """bool [h, W]: True where rows ``row .. row+height`` hold data (not nodata, not masked,
        not transparent)."""
        from rasterio.windows import Window

        window = Window(0, row, self.info.width, height)
        return self._read(lambda: self._src.dataset_mask(window=window), window) > 0

    def _read(self, read: Any, window: Any) -> np.ndarray:
        from rasterio.errors import RasterioError

        try:
            return read()
        except RasterioError as exc:
            raise RasterReadError(
                f"cannot read rows {_span(window.row_off, window.height)}, columns "
                f"{_span(window.col_off, window.width)} of {self.info.path}: {_first_line(exc)}"
            ) from None


def to_uint8(data: np.ndarray, value_range: tuple[float, float] | None) -> np.ndarray:
    """Samples as uint8: as they are when uint8 and no range is given; else ``value_range``
    mapped linearly to 0..255, rounded, values outside clipped."""
    if value_range is None:
        return np.ascontiguousarray(data, dtype=np.uint8)
    low, high = value_range
    scaled = (data.astype(np.float32) - np.float32(low)) * np.float32(255.0 / (high - low))
    return np.clip(np.rint(scaled), 0, 255).astype(np.uint8)


def _span(offset: float, size: float) -> str:
    start = round(offset, 3)
    return f"{start:g}..{round(offset + size, 3):g}"


def _first_line(exc: BaseException) -> str:
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[0] if lines else exc.__class__.__name__
