"""Small GeoTIFFs for the raster tests, written with rasterio as a GIS would write them."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

#: UTM zone 33N (metres) and a 5 cm grid: a drone orthomosaic's georeference.
CRS = "EPSG:32633"
GSD = 0.05
ORIGIN = (500_000.0, 4_000_000.0)


def write_raster(
    path: Path,
    data: np.ndarray,
    *,
    crs: str | None = CRS,
    gsd: float | tuple[float, float] = GSD,
    nodata: float | None = None,
    alpha: bool = False,
    block: int | None = 16,
    mask: np.ndarray | None = None,
) -> Path:
    """Write ``data`` [C, H, W] as a GeoTIFF (tiled in ``block``² tiles, None: stripped);
    ``alpha``: the last band is alpha; ``mask``: an internal per-dataset mask (True = data)."""
    import rasterio.errors
    from rasterio.transform import from_origin

    count, height, width = data.shape
    gx, gy = (gsd, gsd) if isinstance(gsd, int | float) else gsd
    profile = {"driver": "GTiff", "width": width, "height": height, "count": count,
               "dtype": data.dtype.name}  # fmt: skip
    if crs is not None:
        profile.update(crs=crs, transform=from_origin(*ORIGIN, gx, gy))
    if nodata is not None:
        profile["nodata"] = nodata
    if block is not None:
        profile.update(tiled=True, blockxsize=block, blockysize=block, compress="deflate")
    with warnings.catch_warnings():  # no CRS: what the tests make on purpose
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        _write(path, data, profile, alpha, mask)
    return path


def _write(path, data, profile, alpha, mask):
    import rasterio
    from rasterio.enums import ColorInterp

    count = data.shape[0]
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), rasterio.open(path, "w", **profile) as dst:
        dst.write(data)
        if alpha:
            interp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]
            dst.colorinterp = interp[:count]
        if mask is not None:
            dst.write_mask(np.where(mask, 255, 0).astype(np.uint8))


def noise(count: int, height: int, width: int, seed: int = 0, dtype=np.uint8) -> np.ndarray:
    """Smooth-ish random pixels (blocks of 3×3), so a model's classes vary over the raster."""
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    small = rng.integers(0, top, (count, height // 3 + 1, width // 3 + 1), dtype=np.int64)
    return np.repeat(np.repeat(small, 3, 1), 3, 2)[:, :height, :width].astype(dtype)
