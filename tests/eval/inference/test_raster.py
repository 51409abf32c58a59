"""Streamed sliding windows over rasters: the in-memory path's logits, band by band."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from claravid.eval.inference.raster import RowResizer, stream_logits
from claravid.eval.inference.raster_job import raster_logits
from claravid.eval.inference.windows import WindowConfig, sliding_window_logits
from claravid.io.raster import RasterReader
from tests.helpers.rasters import noise, write_raster
from tests.tiny import tiny_model

pytest.importorskip("rasterio")


@pytest.fixture(scope="module")
def model():
    return tiny_model()


def _streamed(model, reader, config, scale=(1.0, 1.0)):
    bands = list(raster_logits(model, reader, config, scale))
    tops = [top for top, _ in bands]
    rows = [logits.shape[1] for _, logits in bands]
    assert tops == list(np.cumsum([0, *rows[:-1]])), "every row once, in order"
    return torch.cat([logits for _, logits in bands], 1)


@pytest.mark.parametrize(
    ("height", "width", "window", "stride", "batch"),
    [
        (47, 61, (28, 42), (19, 25), 3),  # odd sizes; neither axis a whole number of strides
        (95, 30, (28, 28), (13, 13), 4),  # one window a row: a batch spans 4 rows of windows
        (20, 25, (28, 42), (19, 25), 2),  # smaller than one window: padded, then cut
    ],
)
def test_streamed_logits_equal_the_in_memory_path(
    model, tmp_path, height, width, window, stride, batch
):
    """Same windows, order, batches and blending as sliding_window_logits: labels equal, the
    probabilities within 1e-6 (and the logits, summed in the same order, bit for bit)."""
    pixels = noise(3, height, width, seed=height)
    path = write_raster(tmp_path / "r.tif", pixels, block=16)
    config = WindowConfig(size=window, stride=stride, batch_size=batch)
    with torch.inference_mode():
        reference = sliding_window_logits(model, torch.from_numpy(pixels), config)
        with RasterReader(path) as reader:
            streamed = _streamed(model, reader, config)
    assert streamed.shape == reference.shape == (8, height, width)
    assert torch.equal(streamed.argmax(0), reference.argmax(0))
    difference = (streamed.softmax(0) - reference.softmax(0)).abs().max()
    assert difference <= 1e-6
    assert torch.equal(streamed, reference)


def test_rows_are_handed_out_before_the_raster_is_read_through():
    """Streaming: the first finished band comes when only about a window of rows was read, and
    each row is read once."""
    reads = []

    def read_rows(top, n):
        reads.append((top, n))
        return torch.full((3, n, 40), 128, dtype=torch.uint8)

    model = lambda x: x[:, :2]  # noqa: E731  (two 'classes': the first two channels)
    config = WindowConfig(size=(14, 14), stride=(7, 7), batch_size=2, mean=(0.5,) * 3,
                          std=(0.25,) * 3)  # fmt: skip
    bands = stream_logits(model, read_rows, 500, 40, config)
    top, first = next(bands)
    assert top == 0 and first.shape[1] == 7  # rows 0..6: no window after the first row covers them
    assert sum(n for _, n in reads) <= 14 + 7
    rest = list(bands)
    assert [t for t, _ in reads] == list(np.cumsum([0, *[n for _, n in reads][:-1]]))
    assert sum(n for _, n in reads) == 500
    assert first.shape[1] + sum(b.shape[1] for _, b in rest) == 500


@pytest.mark.parametrize(("source", "target"), [((13, 17), (40, 29)), ((40, 29), (13, 17))])
def test_row_resizer_equals_interpolate(source, target):
    """Bilinear resizing band by band equals F.interpolate's (align_corners False) on the whole."""
    torch.manual_seed(1)
    logits = torch.randn(3, *source)
    expected = F.interpolate(logits[None], size=target, mode="bilinear", align_corners=False)[0]
    resizer = RowResizer(source, target)
    out, top = [], 0
    for n in (1, 4, 2, 7, 100):
        band = logits[:, top : top + n]
        out += [rows for _, rows in resizer.push(top, band)] if band.shape[1] else []
        top += band.shape[1]
    got = torch.cat(out, 1)
    assert got.shape == expected.shape
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=0)


def test_a_resampled_raster_agrees_with_the_in_memory_scale(model, tmp_path):
    """Read at 1.5x by GDAL and resized back band by band: nearly the in-memory --scale 1.5
    labels (GDAL's and torch's bilinear differ in rounding, not in kind)."""
    pixels = noise(3, 40, 54, seed=3)
    path = write_raster(tmp_path / "r.tif", pixels)
    config = WindowConfig(size=(28, 28), stride=(19, 19), batch_size=4)
    with torch.inference_mode():
        reference = sliding_window_logits(
            model, torch.from_numpy(pixels), WindowConfig(size=28, stride=19, scale=1.5)
        )
        with RasterReader(path) as reader:
            streamed = _streamed(model, reader, config, scale=(1.5, 1.5))
    assert streamed.shape == reference.shape
    agreement = (streamed.argmax(0) == reference.argmax(0)).float().mean()
    assert agreement >= 0.9, float(agreement)
