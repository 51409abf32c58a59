"""Per-image complexity computed alongside inference, not after it.

:class:`ComplexityJob` starts :func:`claravid.dsp.compute_complexities` (DSP cache first, then
worker processes) in a background thread as soon as the image list is known; the caller runs
its model or reads its predictions meanwhile and collects the values at the end. Decoding and
the histograms release the GIL, so even without worker processes the thread overlaps with the
caller's work.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

from claravid.dsp import METRICS, compute_complexities
from claravid.dsp.metrics import ImageReadError

PRIMARY = "delent"


def parse_measures(text: str | Sequence[str]) -> list[str]:
    """``"delent,glcment"`` -> ``["delent", "glcment"]``; delentropy always first (the bins)."""
    names = [m.strip() for m in (text.split(",") if isinstance(text, str) else text) if m.strip()]
    unknown = [m for m in names if m not in METRICS]
    if unknown:
        raise ValueError(f"unknown measure(s) {unknown} in --measures; choose from {METRICS}")
    return list(dict.fromkeys([PRIMARY, *names]))


class ComplexityJob:
    """Complexity values of ``paths`` for each measure, computed in a background thread.

    Args:
        paths: image files (the RGB frames).
        measures: metric names (``delent``, ``glcment``, ``pixent``).
        workers: worker processes for values missing from the cache (0: in the thread).
        cache: use the DSP cache (``$CLARAVID_CACHE/dsp.sqlite3``).
    """

    def __init__(
        self, paths: Sequence[str], measures: Sequence[str], workers: int = 0, cache: bool = True
    ) -> None:
        self.paths = [str(p) for p in paths]
        self.measures = list(measures)
        self._values: dict[str, list[float]] = {}
        self._error: BaseException | None = None
        self._thread = threading.Thread(
            target=self._run, args=(workers, cache), name="complexity", daemon=True
        )
        self._thread.start()

    def _run(self, workers: int, cache: bool) -> None:
        try:
            for measure in self.measures:
                results, errors = compute_complexities(
                    self.paths, measure, workers=workers, cache=cache
                )
                if errors:
                    first = errors[0]
                    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
                    raise ImageReadError(first.image_path, f"{first.error}{more}")
                self._values[measure] = [r.complexity for r in results]
        except BaseException as exc:  # re-raised in the caller's thread by result()
            self._error = exc

    def result(self) -> dict[str, list[float]]:
        """Wait for the values: ``{measure: [value per path]}``.

        Raises:
            ImageReadError: an image could not be read (the message names it).
        """
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._values
