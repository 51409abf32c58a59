"""Per-image complexity computed alongside inference, not after it.

:class:`ComplexityJob` starts :func:`claravid.dsp.compute_measures` (DSP cache first, then
worker processes) in a background thread as soon as the image list is known; the caller runs
its model or reads its predictions meanwhile and collects the values at the end. Every measure
(and the delentropy of each tile, with a tile size) comes from one decode of the image.
Decoding and the histograms release the GIL, so even without worker processes the thread
overlaps with the caller's work.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numpy as np

from claravid.dsp import compute_measures
from claravid.dsp.metrics import ImageReadError

CHUNK = 8  # images per call in this process: how soon `ComplexityJob.stop` takes effect


class ComplexityJob:
    """Complexity values of ``paths`` for each measure, computed in background threads.

    Args:
        paths: image files (the RGB frames).
        measures: metric names (``delent``, ``glcment``, ``pixent``).
        workers: worker processes for values missing from the cache; worth their start-up
            (about a second each) on long runs. 0 or 1: no processes, ``threads`` threads.
        threads: threads sharing the images when there are no worker processes (decoding,
            blur, Sobel and the histogram release the GIL, so threads scale).
        cache: use the DSP cache (``$CLARAVID_CACHE/dsp.sqlite3``).
        tile_size: also the delentropy of each tile of about this many pixels
            (:mod:`claravid.dsp.tiles`).
    """

    def __init__(
        self,
        paths: Sequence[str],
        measures: Sequence[str],
        workers: int = 0,
        threads: int = 1,
        cache: bool = True,
        tile_size: int | None = None,
    ) -> None:
        self.paths = [str(p) for p in paths]
        self.measures = list(measures)
        self.tile_size = tile_size
        parts = 1 if workers > 1 else max(1, min(threads, len(self.paths)))
        # Interleaved slices: neighbouring frames (similar cost) go to different threads.
        self._slices = [list(range(i, len(self.paths), parts)) for i in range(parts)]
        self._values: dict[str, list[float]] = {m: [0.0] * len(self.paths) for m in measures}
        self._tiles: list[np.ndarray | None] = [None] * len(self.paths)
        self._errors: list[BaseException] = []
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(
                target=self._run, args=(part, workers, cache), name="complexity", daemon=True
            )
            for part in self._slices
        ]
        for thread in self._threads:
            thread.start()

    def _run(self, part: list[int], workers: int, cache: bool) -> None:
        try:
            # In this process: a few images at a time, so `stop` takes effect between them.
            step = len(part) if workers > 1 else CHUNK
            for start in range(0, len(part), step):
                if self._stop.is_set():
                    return
                chunk = part[start : start + step]
                paths = [self.paths[i] for i in chunk]
                results, errors = compute_measures(
                    paths, self.measures, tile_size=self.tile_size, workers=workers, cache=cache
                )
                if errors:
                    first = errors[0]
                    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
                    raise ImageReadError(first.image_path, f"{first.error}{more}")
                for i, result in zip(chunk, results, strict=True):
                    for measure, value in result.values.items():
                        self._values[measure][i] = value
                    self._tiles[i] = result.tiles
        except BaseException as exc:  # re-raised in the caller's thread by result()
            self._errors.append(exc)

    def stop(self) -> None:
        """Stop after the images being measured now and wait for the threads.

        Called when the caller's own work failed: the interpreter must not exit while a thread
        is inside OpenCV (that aborts the process: "terminate called without an active
        exception").
        """
        self._stop.set()
        for thread in self._threads:
            thread.join()

    def result(self) -> dict[str, list[float]]:
        """Wait for the values: ``{measure: [value per path]}`` (tiles: :meth:`tiles`).

        Raises:
            ImageReadError: an image could not be read (the message names it).
        """
        for thread in self._threads:
            thread.join()
        if self._errors:
            raise self._errors[0]
        return self._values

    def tiles(self) -> list[np.ndarray | None]:
        """Wait for the values and return each path's tile delentropies (None without tiles)."""
        self.result()
        return self._tiles
