"""Class maps as Cloud-Optimized GeoTIFFs, written a band of rows at a time.

:class:`ClassMapWriter` takes finished rows in order (uint8 train ids, and optionally a
confidence 0..254) and writes them into a tiled, deflate-compressed GeoTIFF with the input's
size, CRS and transform; rows are buffered up to one row of tiles, so each tile is compressed
once. :meth:`ClassMapWriter.close` then has GDAL's COG driver copy it into a Cloud-Optimized
GeoTIFF (tiles of 512, overviews by nearest neighbour, so an overview pixel is a class, never a
blend of two) and renames that over the output. Both files are hidden temporary names in the
output folder until the last step: an interrupted run leaves nothing that looks finished.

Band 1 holds the class ids with the palette as its colour table; band 2 (optional) the
confidence, the winning class's probability times 254, rounded. Both hold :data:`NODATA` (255)
where the input has no data.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from claravid.infra.files import current_umask
from claravid.io.raster import RasterInfo, require_rasterio

#: The output's nodata value in both bands (also the project's ignore id).
NODATA = 255
#: Confidence 1.0 is written as this (255 is nodata).
CONFIDENCE_MAX = 254
BLOCK = 512


class ClassMapWriter:
    """Write a class map of ``info``'s grid, rows in order, to a COG at ``path``.

    Args:
        path: the final file (written only by :meth:`close`).
        info: the input raster (size, CRS, transform).
        colors: K × 3 uint8 palette colours, class id = row.
        confidence: also write band 2, the confidence.
    """

    def __init__(
        self, path: str | Path, info: RasterInfo, colors: np.ndarray, confidence: bool = False
    ) -> None:
        rasterio = require_rasterio()
        self.path = Path(path)
        self.width, self.height = info.width, info.height
        self.bands = 2 if confidence else 1
        self._rows = 0  # rows handed to write_rows so far
        self._buffer = np.full((self.bands, BLOCK, self.width), NODATA, np.uint8)
        self._buffered = 0
        self._flushed = 0  # rows in the file
        self._temps: list[Path] = []
        self._stage = self._temp(".partial.tif")
        profile: dict[str, Any] = {
            "driver": "GTiff", "width": self.width, "height": self.height, "count": self.bands,
            "dtype": "uint8", "nodata": NODATA, "tiled": True, "blockxsize": BLOCK,
            "blockysize": BLOCK, "compress": "deflate", "BIGTIFF": "IF_SAFER",
        }  # fmt: skip
        if info.crs is not None:
            profile["crs"] = info.crs
        if info.transform is not None and not info.transform.is_identity:
            profile["transform"] = info.transform
        with warnings.catch_warnings():  # no CRS: inspect said so already, once
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            self._dst = rasterio.open(self._stage, "w", **profile)
        table = {i: (*(int(v) for v in c), 255) for i, c in enumerate(np.asarray(colors))}
        self._dst.write_colormap(1, table)
        self._dst.set_band_description(1, "class")
        if confidence:
            self._dst.set_band_description(2, f"confidence (probability x {CONFIDENCE_MAX})")

    def _temp(self, suffix: str) -> Path:
        fd, name = tempfile.mkstemp(
            prefix=f".{self.path.name}.", suffix=suffix, dir=self.path.parent
        )
        os.close(fd)
        self._temps.append(Path(name))
        return Path(name)

    def write_rows(self, labels: np.ndarray, confidence: np.ndarray | None = None) -> None:
        """The next rows: ``labels`` uint8 [h, W] (NODATA where there is no data) and, with a
        confidence band, ``confidence`` uint8 [h, W]."""
        if labels.shape[1:] != (self.width,) or self._rows + len(labels) > self.height:
            raise ValueError(f"rows of width {self.width} up to {self.height} in all expected")
        done = 0
        while done < len(labels):
            take = min(BLOCK - self._buffered, len(labels) - done)
            rows = slice(self._buffered, self._buffered + take)
            self._buffer[0, rows] = labels[done : done + take]
            if self.bands == 2:
                assert confidence is not None, "this writer has a confidence band"
                self._buffer[1, rows] = confidence[done : done + take]
            self._buffered += take
            done += take
            if self._buffered == BLOCK:
                self._flush()
        self._rows += len(labels)

    def _flush(self) -> None:
        from rasterio.windows import Window

        if self._buffered:
            window = Window(0, self._flushed, self.width, self._buffered)
            self._dst.write(self._buffer[:, : self._buffered], window=window)
            self._flushed += self._buffered
            self._buffered = 0

    def close(self) -> Path:
        """Finish: flush, convert to a COG, rename over ``path``; returns ``path``."""
        import rasterio.errors
        import rasterio.shutil

        if self._rows != self.height:
            self.abort()
            raise ValueError(f"{self._rows} of {self.height} rows written")
        self._flush()
        self._dst.close()
        final = self._temp(".tif")
        final.unlink()  # the COG driver creates the file itself
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            rasterio.shutil.copy(
                self._stage, final, driver="COG", COMPRESS="DEFLATE", BLOCKSIZE=BLOCK,
                RESAMPLING="NEAREST", OVERVIEWS="AUTO", BIGTIFF="IF_SAFER",
            )  # fmt: skip
        os.chmod(final, 0o666 & ~current_umask())
        os.replace(final, self.path)
        self._remove_temps()
        return self.path

    def abort(self) -> None:
        """Close and remove the temporary files (nothing is left in the output folder)."""
        if not self._dst.closed:
            self._dst.close()
        self._remove_temps()

    def _remove_temps(self) -> None:
        for temp in self._temps:
            temp.unlink(missing_ok=True)
        self._temps.clear()
