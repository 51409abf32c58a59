"""Statistics every per-bin table shares: correlations, a group's DSP profile, order checks.

The per-image tables of mIoU (:mod:`claravid.eval.analysis.miou_bins`), of tiles
(:mod:`claravid.eval.analysis.tile_bins`) and of any per-image metric
(:mod:`claravid.eval.analysis.metric_bins`) correlate complexity with a per-image value, describe
each group by the DSP profile of its delentropy, and warn where intervals do not support the
order of adjacent bins; each of those rules is written once, here.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from claravid.dsp.profile import DegenerateProfileWarning, fit_profile
from claravid.eval.analysis.metrics import finite_or_none


def correlation(x: ArrayLike, y: ArrayLike) -> dict[str, Any]:
    """Pearson and Spearman (scipy) over the pairs where both values are finite, with n."""
    xs, ys = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    keep = np.isfinite(xs) & np.isfinite(ys)
    xs, ys = xs[keep], ys[keep]
    out: dict[str, Any] = {"pearson": None, "spearman": None, "n": int(keep.sum())}
    # A correlation needs 3 points and some spread in both variables.
    if len(xs) >= 3 and np.ptp(xs) > 0 and np.ptp(ys) > 0:
        out["pearson"] = finite_or_none(float(stats.pearsonr(xs, ys).statistic))
        out["spearman"] = finite_or_none(float(stats.spearmanr(xs, ys).statistic))
    return out


def group_profile(values: np.ndarray) -> dict[str, Any]:
    """The DSP profile (μ, σ, α, β) of a group's delentropy values, None where undefined.

    α and β need at least :data:`MIN_BETA_FIT` values: the fit scales the range to [0, 1], so two
    values are always its two ends and their "fit" (α = β ≈ 0) says nothing. Then α and β are
    None and ``note`` says why.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateProfileWarning)
        profile = fit_profile(values.tolist())
    out: dict[str, Any] = {
        k: finite_or_none(getattr(profile, k)) for k in ("mu", "sigma", "alpha", "beta")
    }
    n = int(np.isfinite(np.asarray(values, dtype=float)).sum())
    if n < MIN_BETA_FIT:
        out["alpha"] = out["beta"] = None
        out["note"] = (f"a Beta fit needs at least {MIN_BETA_FIT} images, the group has {n}: its "
                       "two ends are scaled to 0 and 1, which fixes no shape")  # fmt: skip
    elif out["alpha"] is None and out["sigma"] == 0:
        out["note"] = "all delentropy values are equal: no Beta shape"
    return out


#: The fewest values a group's Beta fit (α, β) is reported for.
MIN_BETA_FIT = 3


def order_warnings(rows: Sequence[Mapping[str, Any]], ci: str, value: str) -> list[str]:
    """Adjacent bins whose order the intervals do not support.

    Two adjacent bins' order is unsupported when each one's point estimate lies inside the
    other's interval (the intervals overlap past both estimates).
    """
    out = []
    for a, b in itertools.pairwise(rows):
        va, vb, ca, cb = a.get(value), b.get(value), a.get(ci), b.get(ci)
        if None in (va, vb) or not ca or not cb:
            continue
        if ca[0] <= vb <= ca[1] and cb[0] <= va <= cb[1]:
            out.append(
                f"bins {a['name']} ({va:.3f} [{ca[0]:.3f}, {ca[1]:.3f}]) and {b['name']} "
                f"({vb:.3f} [{cb[0]:.3f}, {cb[1]:.3f}]): each estimate lies inside the other's "
                "interval, so their order is not supported by the data"
            )
    return out
