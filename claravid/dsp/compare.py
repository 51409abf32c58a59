"""Profiles side by side, with the comparability checks of the supplementary material (§8.2).

DSP is stable under about 10 % change of image resolution but shifts from about 25 %: profiles of
collections whose resolutions differ by more than 10 % are flagged as not comparable, as are
profiles of different metrics or blur settings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from claravid.dsp.collection import ProfileRun

#: Largest relative difference of linear resolution under which profiles stay comparable.
RESOLUTION_TOLERANCE = 0.10


def typical_resolution(run: ProfileRun) -> tuple[int, int] | None:
    """Median (height, width) of the run's images, or None when the file has no sizes."""
    sizes = [(r.height, r.width) for r in run.results if r.height and r.width]
    if not sizes:
        return None
    arr = np.asarray(sizes, dtype=np.float64)
    return int(np.median(arr[:, 0])), int(np.median(arr[:, 1]))


def comparability_warnings(runs: Sequence[ProfileRun], names: Sequence[str]) -> list[str]:
    """Reasons the profiles should not be compared directly (empty when they can be)."""
    notes = []
    settings = {(r.metric, r.use_blur, r.blur_ksize if r.use_blur else None) for r in runs}
    if len(settings) > 1:
        notes.append(f"metric/blur settings differ ({sorted(settings, key=str)}): not comparable")
    scale = {}
    for run, name in zip(runs, names, strict=True):
        res = typical_resolution(run)
        if res is None:
            notes.append(f"{name}: image sizes unknown (official JSON); resolution not checked")
        else:
            scale[name] = math.sqrt(res[0] * res[1])
    if len(scale) > 1:
        lo_name = min(scale, key=scale.__getitem__)
        hi_name = max(scale, key=scale.__getitem__)
        ratio = scale[hi_name] / scale[lo_name]
        if ratio > 1 + RESOLUTION_TOLERANCE:
            notes.append(
                f"image resolutions differ by {100 * (ratio - 1):.0f} % ({hi_name} vs {lo_name}); "
                "DSP shifts with resolution beyond ~10 % (supplementary §8.2): resize to a common "
                "resolution before comparing these profiles"
            )
    return notes


def _fmt(value: float) -> str:
    return f"{value:.3f}" if math.isfinite(value) else "n/a"


def compare_table(runs: Sequence[ProfileRun], names: Sequence[str] | None = None) -> str:
    """A plain-text table: one row per run with n, resolution, mu, sigma, alpha, beta, a, b."""
    names = (
        list(names) if names is not None else [r.source or f"run {i}" for i, r in enumerate(runs)]
    )
    header = ["profile", "metric", "n", "resolution", "mu", "sigma", "alpha", "beta", "a", "b"]
    rows = []
    for run, name in zip(runs, names, strict=True):
        p = run.profile
        res = typical_resolution(run)
        rows.append(
            [
                name,
                run.metric,
                str(len(run.results)),
                f"{res[1]}x{res[0]}" if res else "?",
                *(_fmt(getattr(p, k)) for k in ("mu", "sigma", "alpha", "beta", "a", "b")),
            ]
        )
    widths = [max(len(str(c)) for c in col) for col in zip(header, *rows, strict=True)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) for row in rows]
    notes = comparability_warnings(runs, names)
    lines += [f"WARNING: {n}" for n in notes]
    return "\n".join(lines)
