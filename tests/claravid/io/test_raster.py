"""Reading rasters for the models: bands, sample types, masks, georeference, bad inputs."""

import sys

import numpy as np
import pytest

from claravid.io.raster import (
    NoCrsWarning,
    RasterError,
    RasterReader,
    RasterReadError,
    parse_bands,
    parse_value_range,
    require_rasterio,
)
from tests.helpers.rasters import noise, write_raster

rasterio = pytest.importorskip("rasterio")


def test_rgb_rows_as_stored(tmp_path):
    pixels = noise(3, 37, 29)
    path = write_raster(tmp_path / "a.tif", pixels)
    with RasterReader(path) as r:
        assert (r.info.width, r.info.height, r.info.bands) == (29, 37, (1, 2, 3))
        np.testing.assert_array_equal(r.read_rows(5, 20), pixels[:, 5:25])
        assert r.read_mask(0, 37).all()
        assert r.info.gsd() == (0.05, 0.05)


def test_bands_choose_and_order_the_channels(tmp_path):
    pixels = noise(5, 10, 12)
    path = write_raster(tmp_path / "five.tif", pixels)
    with pytest.raises(RasterError, match=r"has 5 bands.*--bands"):
        RasterReader(path)
    with RasterReader(path, bands=parse_bands("5,1,3")) as r:
        np.testing.assert_array_equal(r.read_rows(0, 10), pixels[[4, 0, 2]])
    with pytest.raises(RasterError, match=r"has 5 bands \(1\.\.5\)"):
        RasterReader(path, bands=(1, 2, 6))
    with pytest.raises(RasterError, match="three band numbers"):
        parse_bands("1,2")


def test_a_grey_raster_asks_for_bands(tmp_path):
    path = write_raster(tmp_path / "grey.tif", noise(1, 8, 8))
    with pytest.raises(RasterError, match=r"1 band, not RGB or RGBA: pass --bands.*1,1,1"):
        RasterReader(path)


def test_rgba_alpha_is_the_mask(tmp_path):
    pixels = noise(4, 9, 11)
    pixels[3] = 255
    pixels[3, 2:4, 5:9] = 0  # transparent
    path = write_raster(tmp_path / "rgba.tif", pixels, alpha=True)
    with RasterReader(path) as r:
        assert r.info.bands == (1, 2, 3)
        np.testing.assert_array_equal(r.read_rows(0, 9), pixels[:3])
        valid = r.read_mask(0, 9)
    expected = np.ones((9, 11), bool)
    expected[2:4, 5:9] = False
    np.testing.assert_array_equal(valid, expected)


def test_nodata_values_and_internal_masks_fold_into_the_mask(tmp_path):
    pixels = noise(3, 8, 10, seed=2) | 1  # no zeros by chance
    pixels[:, 1, 2] = 0  # nodata in every band: no data there
    path = write_raster(tmp_path / "nodata.tif", pixels, nodata=0)
    with RasterReader(path) as r:
        valid = r.read_mask(0, 8)
    assert not valid[1, 2] and valid.sum() == 8 * 10 - 1
    mask = np.ones((8, 10), bool)
    mask[5:, :3] = False
    path = write_raster(tmp_path / "masked.tif", noise(3, 8, 10), mask=mask)
    with RasterReader(path) as r:
        np.testing.assert_array_equal(r.read_mask(2, 6), mask[2:8])


def test_uint16_needs_a_value_range(tmp_path):
    pixels = np.zeros((3, 2, 3), np.uint16)
    pixels[:, 0] = [0, 4095, 2048]
    pixels[:, 1] = [5000, 100, 65535]
    path = write_raster(tmp_path / "u16.tif", pixels)
    with pytest.raises(RasterError, match="uint16 samples: pass --value-range LOW,HIGH"):
        RasterReader(path)
    with RasterReader(path, value_range=parse_value_range("0,4095")) as r:
        got = r.read_rows(0, 2)
    # 2048·255/4095 = 127.53 -> 128; 100·255/4095 = 6.23 -> 6; above 4095 clipped to 255.
    np.testing.assert_array_equal(got[0], [[0, 255, 128], [255, 6, 255]])
    with pytest.raises(RasterError, match="LOW < HIGH"):
        parse_value_range("10,10")


def test_no_crs_warns_and_has_no_gsd(tmp_path):
    path = write_raster(tmp_path / "plain.tif", noise(3, 8, 8), crs=None)
    with pytest.warns(NoCrsWarning, match="has no CRS"), RasterReader(path) as r:
        assert r.info.crs is None and r.info.gsd() is None


def test_gsd_in_metres_from_feet_and_none_from_degrees(tmp_path):
    feet = write_raster(tmp_path / "ft.tif", noise(3, 4, 4), crs="EPSG:2263", gsd=(0.25, 0.5))
    with RasterReader(feet) as r:
        gx, gy = r.info.gsd()
    assert gx == pytest.approx(0.25 * 0.3048006096, rel=1e-6)  # US survey feet
    assert gy == pytest.approx(0.5 * 0.3048006096, rel=1e-6)
    degrees = write_raster(tmp_path / "deg.tif", noise(3, 4, 4), crs="EPSG:4326", gsd=1e-6)
    with RasterReader(degrees) as r:
        assert r.info.gsd() is None


def test_a_block_that_fails_to_decode_names_the_window(tmp_path):
    pixels = noise(3, 64, 48)
    path = write_raster(tmp_path / "bad.tif", pixels, block=16)
    with rasterio.open(path) as src:
        offset = int(src.get_tag_item("BLOCK_OFFSET_1_2", "TIFF", bidx=1))
        size = int(src.get_tag_item("BLOCK_SIZE_1_2", "TIFF", bidx=1))
    with open(path, "r+b") as f:  # the tile of rows 32..47, columns 16..31, band 1
        f.seek(offset)
        f.write(b"\xff" * size)
    with RasterReader(path) as r:
        np.testing.assert_array_equal(r.read_rows(0, 16), pixels[:, :16])
        with pytest.raises(RasterReadError, match=r"cannot read rows 20\.\.40, columns 0\.\.48"):
            r.read_rows(20, 20)


def test_missing_or_foreign_files(tmp_path):
    with pytest.raises(RasterError, match="not found"):
        RasterReader(tmp_path / "none.tif")
    (tmp_path / "text.tif").write_text("not a raster")
    with pytest.raises(RasterError, match=r"cannot open .*text\.tif as a raster"):
        RasterReader(tmp_path / "text.tif")


def test_without_rasterio_one_line_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "rasterio", None)
    with pytest.raises(RasterError, match=r"needs rasterio: pip install 'claravid-toolkit\[geo\]'"):
        require_rasterio()
