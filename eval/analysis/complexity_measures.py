"""The complexity measures a report can carry, and the one its bins are made of.

``delent`` (delentropy, the DSP measure) is always computed and listed first: bins and tiles are
made of it. ``glcment`` (GLCM entropy) and ``pixent`` (pixel entropy) are the baselines the
ClaraVid paper compares it with (:mod:`claravid.dsp.measures`).
"""

from __future__ import annotations

from collections.abc import Sequence

from claravid.dsp.measures import METRICS

#: The measure bins are made of (always computed, listed first).
PRIMARY_MEASURE = "delent"


def parse_measures(text: str | Sequence[str]) -> list[str]:
    """``"delent,glcment"`` -> ``["delent", "glcment"]``; delentropy always first (the bins)."""
    names = [m.strip() for m in (text.split(",") if isinstance(text, str) else text) if m.strip()]
    unknown = [m for m in names if m not in METRICS]
    if unknown:
        raise ValueError(f"unknown measure(s) {unknown} in --measures; choose from {METRICS}")
    return list(dict.fromkeys([PRIMARY_MEASURE, *names]))
