"""Sliding windows over a raster larger than memory, a band of rows at a time.

The windows, their order, their batches and the blending are those of
:func:`claravid.eval.inference.windows.sliding_window_logits` (same starts, last window flush
with the border, logits summed in the same order and divided by the per-pixel window count, a
raster smaller than a window padded with zeros after normalisation), so on a raster that fits
in memory the averaged logits are the in-memory path's, bit for bit. What differs is what is
held: the pixels and the logit sums of the rows that windows not yet run still overlap (about
one window's height, the whole width), never the whole raster. Rows are handed out as soon as
no later window covers them.

The window count per pixel is the product of a per-row and a per-column count (the windows form
a grid), so no count map is kept either.

A raster at another ground sampling distance than the model's is resampled while it is read
(GDAL's bilinear, :meth:`claravid.io.raster.RasterReader.read_rows`), and the logits of each
finished band are resized back to the raster's own grid (bilinear, the in-memory path's
``align_corners=False`` rule), so the output always has the input's size.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import torch

from claravid.eval.inference.windows import Model, WindowConfig, _forward, normalise, window_starts

#: Rows handed out at a time (bounds the softmax and writing temporaries to this many rows).
EMIT_ROWS = 64
ReadRows = Callable[[int, int], torch.Tensor]


def _counts(length: int, starts: list[int], window: int) -> torch.Tensor:
    counts = torch.zeros(length, dtype=torch.float32)
    for s in starts:
        counts[s : s + window] += 1
    return counts


def _ring(start: int, stop: int, capacity: int) -> Iterator[tuple[slice, slice]]:
    """(ring slice, offset slice) pieces of rows ``start .. stop`` kept at ``row % capacity``."""
    row = start
    while row < stop:
        at = row % capacity
        n = min(stop - row, capacity - at)
        yield slice(at, at + n), slice(row - start, row - start + n)
        row += n


def window_count(height: int, width: int, config: WindowConfig) -> int:
    """How many windows ``config`` (resolved for a model) cuts from a ``height`` × ``width``
    image (after padding a small one to a window)."""
    assert config.size is not None and config.stride is not None
    (wh, ww), (sh, sw) = config.size, config.stride
    rows = window_starts(max(height, wh), wh, sh)
    return len(rows) * len(window_starts(max(width, ww), ww, sw))


def stream_logits(
    model: Model,
    read_rows: ReadRows,
    height: int,
    width: int,
    config: WindowConfig,
    progress: Callable[[int], Any] | None = None,
) -> Iterator[tuple[int, torch.Tensor]]:
    """Averaged window logits of a ``height`` × ``width`` image, in bands of finished rows.

    Args:
        model: as :func:`~claravid.eval.inference.windows.sliding_window_logits` takes.
        read_rows: ``read_rows(top, n)`` gives rows ``top .. top+n`` as uint8 [3, n, width];
            called with increasing ``top``, each row once.
        height, width: the image's size.
        config: windows, batch size, precision, normalisation (``scale`` must be 1: resample
            in ``read_rows``); what it leaves unset comes from the model.
        progress: called with the number of windows of each batch once it has run.

    Yields:
        ``(top, logits)``: float32 [K, n, width] of rows ``top .. top+n`` on the CPU, every row
        once, in order, at most :data:`EMIT_ROWS` at a time.
    """
    config = config.for_model(model)
    if config.scale != 1.0:
        raise ValueError("stream_logits runs at scale 1: resample the rows as they are read")
    assert config.size is not None and config.stride is not None  # for_model sets both
    (wh, ww), (sh, sw) = config.size, config.stride
    ph, pw = max(height, wh), max(width, ww)  # a small image is padded to one window
    ys, xs = window_starts(ph, wh, sh), window_starts(pw, ww, sw)
    boxes = [(y, x) for y in ys for x in xs]
    chunks = [boxes[i : i + config.batch_size] for i in range(0, len(boxes), config.batch_size)]
    capacity = min(ph, max(c[-1][0] - c[0][0] for c in chunks) + wh)
    row_hits, col_hits = _counts(ph, ys, wh), _counts(pw, xs, ww)
    device = _device(model)
    band = torch.zeros((3, 0, width), dtype=torch.uint8, device=device)  # rows band_top ..
    band_top = 0
    sums: torch.Tensor | None = None  # [K, capacity, pw], row r at r % capacity
    done = 0  # rows handed out
    for index, chunk in enumerate(chunks):
        first, last = chunk[0][0], chunk[-1][0]
        band, band_top = _advance(band, band_top, first, last + wh, height, read_rows)
        batch = torch.stack([_window(band, band_top, y, x, (wh, ww), config) for y, x in chunk])
        out = _forward(model, batch.contiguous(), config)
        if sums is None:
            sums = torch.zeros((out.shape[1], capacity, pw), dtype=torch.float32, device=device)
        for (y, x), window_logits in zip(chunk, out, strict=True):
            for ring, part in _ring(y, y + wh, capacity):
                sums[:, ring, x : x + ww] += window_logits[:, part]
        if progress is not None:
            progress(len(chunk))
        finished = chunks[index + 1][0][0] if index + 1 < len(chunks) else ph
        for top in range(done, min(finished, height), EMIT_ROWS):
            stop = min(top + EMIT_ROWS, finished, height)
            yield top, _average(sums, top, stop, capacity, row_hits, col_hits, width)
        for ring, _ in _ring(done, finished, capacity):
            sums[:, ring] = 0
        done = finished


def _average(
    sums: torch.Tensor,
    top: int,
    stop: int,
    capacity: int,
    row_hits: torch.Tensor,
    col_hits: torch.Tensor,
    width: int,
) -> torch.Tensor:
    parts = [sums[:, ring] for ring, _ in _ring(top, stop, capacity)]
    rows = parts[0] if len(parts) == 1 else torch.cat(parts, 1)
    hits = row_hits[top:stop, None] * col_hits[None, :]  # exact small integers, as counted
    return (rows / hits.to(rows.device))[:, :, :width].cpu()


def _advance(
    band: torch.Tensor, band_top: int, first: int, stop: int, height: int, read_rows: ReadRows
) -> tuple[torch.Tensor, int]:
    """The uint8 band holding rows ``first .. stop`` (those inside the image), dropping the rows
    above ``first`` that no window still needs."""
    band_stop = band_top + band.shape[1]
    if first > band_top:
        band = band[:, min(first, band_stop) - band_top :]
        band_top = first
        band_stop = max(band_stop, first)
    stop = min(stop, height)
    if stop <= band_stop:
        return band, band_top
    rows = read_rows(band_stop, stop - band_stop).to(band.device)
    return torch.cat([band, rows], 1), band_top


def _window(
    band: torch.Tensor, top: int, y: int, x: int, size: tuple[int, int], config: WindowConfig
) -> torch.Tensor:
    """One window, normalised; past the image's bottom or right, zeros after normalisation (as
    the in-memory path pads an image smaller than a window)."""
    wh, ww = size
    crop = normalise(band[:, y - top : y - top + wh, x : x + ww], config)
    if crop.shape[1:] != (wh, ww):
        crop = torch.nn.functional.pad(crop, (0, ww - crop.shape[2], 0, wh - crop.shape[1]))
    return crop


def _device(model: Any) -> torch.device:
    if isinstance(model, torch.nn.Module):
        for p in model.parameters():
            return p.device
    return torch.device("cpu")


class RowResizer:
    """Bilinear resizing of logits handed out in bands of rows (``align_corners=False``, as
    ``torch.nn.functional.interpolate``), from ``(h, w)`` to ``(height, width)``: each output
    row is made as soon as its two source rows have arrived."""

    def __init__(self, source: tuple[int, int], target: tuple[int, int]) -> None:
        (self.h, w), (self.height, width) = source, target
        self.y0, self.y1, self.ly = _taps(self.h, self.height)
        self.x0, self.x1, self.lx = _taps(w, width)
        self.rows = torch.zeros((0, 0, w))
        self.rows_top = 0
        self.done = 0

    def push(self, top: int, logits: torch.Tensor) -> Iterator[tuple[int, torch.Tensor]]:
        """Take source rows ``top ..``; yield ``(row, logits [K, n, width])`` of the output rows
        they complete."""
        if self.rows.numel() == 0:
            self.rows, self.rows_top = logits, top
        else:
            self.rows = torch.cat([self.rows, logits], 1)
        have = self.rows_top + self.rows.shape[1]
        stop = self.done
        while stop < self.height and int(self.y1[stop]) < have:
            stop += 1
        for top_out in range(self.done, stop, EMIT_ROWS):
            end = min(top_out + EMIT_ROWS, stop)
            yield top_out, self._rows(top_out, end)
        self.done = stop
        if stop < self.height:  # keep the source rows later output rows still need
            keep = int(self.y0[stop]) - self.rows_top
            self.rows, self.rows_top = self.rows[:, keep:], self.rows_top + keep

    def _rows(self, top: int, stop: int) -> torch.Tensor:
        y0 = self.y0[top:stop] - self.rows_top
        y1 = self.y1[top:stop] - self.rows_top
        ly = self.ly[top:stop, None]
        upper, lower = self.rows[:, y0], self.rows[:, y1]
        lx = self.lx[None, :]
        upper = upper[:, :, self.x0] * (1 - lx) + upper[:, :, self.x1] * lx
        lower = lower[:, :, self.x0] * (1 - lx) + lower[:, :, self.x1] * lx
        return upper * (1 - ly) + lower * ly


def _taps(source: int, target: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Source index pairs and weights of bilinear resizing along one axis (align_corners False:
    source = (i + 0.5)·source/target − 0.5, clamped at 0)."""
    scale = np.float32(source / target)
    centre = np.maximum((np.arange(target, dtype=np.float32) + 0.5) * scale - 0.5, 0)
    first = np.minimum(centre.astype(np.int64), source - 1)
    second = np.minimum(first + 1, source - 1)
    weight = (centre - first).astype(np.float32)
    return torch.from_numpy(first), torch.from_numpy(second), torch.from_numpy(weight)
