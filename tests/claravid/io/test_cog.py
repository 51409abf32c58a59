"""Class maps written as Cloud-Optimized GeoTIFFs: georeference, palette, nodata, atomicity."""

import numpy as np
import pytest

from claravid.io.cog import NODATA, ClassMapWriter
from claravid.io.raster import RasterReader
from tests.helpers.rasters import noise, write_raster

rasterio = pytest.importorskip("rasterio")

COLORS = np.array([[10, 20, 30], [200, 0, 0], [0, 255, 0]], np.uint8)


def _info(tmp_path, height, width, **kwargs):
    path = write_raster(tmp_path / "in.tif", noise(3, height, width), **kwargs)
    with RasterReader(path) as r:
        return r.info


def test_a_cog_with_the_inputs_grid_palette_and_nodata(tmp_path):
    height, width = 1100, 700  # over one 512 tile each way: overviews and a partial tile row
    info = _info(tmp_path, height, width, block=256)
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 3, (height, width), dtype=np.uint8)
    labels[:40, :50] = NODATA
    conf = rng.integers(0, 255, (height, width), dtype=np.uint8)
    out = tmp_path / "out" / "map.tif"
    out.parent.mkdir()
    writer = ClassMapWriter(out, info, COLORS, confidence=True)
    for top in range(0, height, 333):  # bands of any height, not tile-aligned
        writer.write_rows(labels[top : top + 333], conf[top : top + 333])
    assert writer.close() == out
    assert [p.name for p in out.parent.iterdir()] == ["map.tif"]  # no temporary left
    with rasterio.open(out) as src:
        assert src.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        assert src.profile["compress"] == "deflate" and src.profile["tiled"]
        assert src.block_shapes == [(512, 512)] * 2
        assert src.overviews(1) == [2, 4]
        assert (src.crs, src.transform) == (info.crs, info.transform)
        assert (src.width, src.height, src.count, src.nodata) == (700, 1100, 2, NODATA)
        assert src.colormap(1)[1] == (200, 0, 0, 255) and src.colormap(1)[0] == (10, 20, 30, 255)
        np.testing.assert_array_equal(src.read(1), labels)
        np.testing.assert_array_equal(src.read(2), conf)
        # Overviews by nearest neighbour: every pixel a class or nodata, never a blend.
        small = src.read(1, out_shape=(275, 175))
        assert set(np.unique(small)) <= {0, 1, 2, NODATA}


def test_an_unfinished_map_leaves_nothing(tmp_path):
    info = _info(tmp_path, 30, 20)
    out = tmp_path / "out"
    out.mkdir()
    writer = ClassMapWriter(out / "map.tif", info, COLORS)
    writer.write_rows(np.zeros((10, 20), np.uint8))
    assert len(list(out.iterdir())) == 1  # the hidden partial file, while writing
    with pytest.raises(ValueError, match="10 of 30 rows written"):
        writer.close()
    assert list(out.iterdir()) == []
    writer = ClassMapWriter(out / "map.tif", info, COLORS)
    writer.abort()
    assert list(out.iterdir()) == []


def test_no_crs_in_none_out(tmp_path):
    with pytest.warns(UserWarning, match="no CRS"):
        info = _info(tmp_path, 12, 9, crs=None)
    writer = ClassMapWriter(tmp_path / "map.tif", info, COLORS)
    writer.write_rows(np.ones((12, 9), np.uint8))
    with rasterio.open(writer.close()) as src:
        assert src.crs is None
        np.testing.assert_array_equal(src.read(1), 1)
