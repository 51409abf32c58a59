"""The official scene profile recipe (docs/complexity.md), written out with numpy and scipy.

Independent of ``claravid.dsp.profile``: the expected values of the profile tests come from here,
so a slip in the code under test (sample instead of population sigma, no clipping, alpha and
beta swapped, the wrong scaling) cannot also move the expectation.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.stats import beta


def official_profile(values) -> dict[str, float]:
    """mu, sigma (ddof 0), a = min, b = max, and the Beta(alpha, beta) moment fit of the values
    scaled to [0, 1] and clipped to [1e-6, 1 - 1e-6], with location 0 and scale 1."""
    h = np.asarray(values, dtype=np.float64)
    a, b = h.min(), h.max()
    scaled = np.clip((h - a) / (b - a), 1e-6, 1 - 1e-6)
    with warnings.catch_warnings():  # scipy's solver warns about its own steps on small samples
        warnings.simplefilter("ignore", RuntimeWarning)
        alpha, beta_, loc, scale = beta.fit(scaled, floc=0, fscale=1, method="MM")
    assert (loc, scale) == (0, 1)
    return {
        "mu": float(np.mean(h)),
        "sigma": float(np.sqrt(np.mean((h - np.mean(h)) ** 2))),
        "alpha": float(alpha),
        "beta": float(beta_),
        "a": float(a),
        "b": float(b),
    }


def moments_beta(values) -> tuple[float, float]:
    """The method-of-moments Beta shapes in closed form: alpha = m c, beta = (1 - m) c with
    c = m (1 - m) / v - 1 (m, v the mean and population variance of the scaled values)."""
    h = np.asarray(values, dtype=np.float64)
    scaled = np.clip((h - h.min()) / (h.max() - h.min()), 1e-6, 1 - 1e-6)
    m, v = scaled.mean(), scaled.var()
    c = m * (1 - m) / v - 1
    return float(m * c), float((1 - m) * c)
