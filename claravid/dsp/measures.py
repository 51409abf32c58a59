"""The complexity measures by name: the official three, in the official order, and their titles.

Names only, no image code: the numpy-only analysis layer of ``claravid.eval`` lists and checks
measures through this module without loading OpenCV or any file reader
(:mod:`claravid.dsp.metrics` computes them).
"""

from __future__ import annotations

#: The official metric names, in the official order.
METRICS: tuple[str, ...] = ("delent", "glcment", "pixent")
#: Human-readable names, for titles and tables.
METRIC_NAMES: dict[str, str] = {
    "delent": "Delentropy",
    "glcment": "GLCM Entropy",
    "pixent": "Pixel Entropy",
}
