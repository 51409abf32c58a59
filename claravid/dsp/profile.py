"""The scene complexity profile: moments of the per-image values and a Beta fit, as official.

Official ``ComplexityProfile.beta_fit``: a = min, b = max, scale to [0, 1] by (H - a) / (b - a),
clip to [1e-6, 1 - 1e-6], then ``scipy.stats.beta.fit(scaled, floc=0, fscale=1, method="MM")``;
the plot's mu and sigma are ``mean()`` and the population ``std()``. Degenerate input (no value, one
value, all values equal, NaNs) gives a defined result and a :class:`DegenerateProfileWarning`
instead of the official division by zero.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

#: The official clip keeping scaled values strictly inside (0, 1).
EPS = 1e-6
#: The keys of a profile in JSON, in order.
PROFILE_KEYS: tuple[str, ...] = ("mu", "sigma", "alpha", "beta", "a", "b")


class DegenerateProfileWarning(UserWarning):
    """The values cannot support a full profile (none, one, all equal, or NaNs were dropped)."""


@dataclass(frozen=True)
class Profile:
    """A scene complexity profile.

    Attributes:
        mu: mean complexity.
        sigma: population standard deviation (ddof 0).
        alpha: Beta shape alpha of the min-max scaled values (NaN when undefined).
        beta: Beta shape beta (NaN when undefined).
        a: smallest value (the scaling's lower end).
        b: largest value (the scaling's upper end).
        n: number of finite values the profile was fitted on.
    """

    mu: float
    sigma: float
    alpha: float
    beta: float
    a: float
    b: float
    n: int = 0

    def to_dict(self) -> dict[str, float | None]:
        """The six JSON keys; undefined (NaN) values become None, i.e. JSON null."""
        return {k: _json_float(getattr(self, k)) for k in PROFILE_KEYS}

    @classmethod
    def from_dict(cls, data: dict[str, Any], n: int = 0) -> Profile:
        """Rebuild from :meth:`to_dict` output (None -> NaN)."""
        missing = [k for k in PROFILE_KEYS if k not in data]
        if missing:
            raise ValueError(f"profile is missing {', '.join(missing)}; expected {PROFILE_KEYS}")
        values = {k: math.nan if data[k] is None else float(data[k]) for k in PROFILE_KEYS}
        return cls(**values, n=n)

    def pdf(self, x: np.ndarray) -> np.ndarray:
        """The fitted density on the complexity axis (Beta pdf of the scaled value / (b - a))."""
        from scipy.stats import beta as beta_dist

        x = np.asarray(x, dtype=np.float64)
        if not (math.isfinite(self.alpha) and math.isfinite(self.beta)) or self.b <= self.a:
            return np.full(x.shape, np.nan)
        return beta_dist.pdf((x - self.a) / (self.b - self.a), self.alpha, self.beta) / (
            self.b - self.a
        )


def _json_float(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _beta_mm(scaled: np.ndarray) -> tuple[float, float]:
    """scipy's method-of-moments Beta fit with loc 0 and scale 1, as the official code calls it."""
    from scipy.stats import beta as beta_dist

    with warnings.catch_warnings():
        # scipy's moment solver warns about its own intermediate steps (sqrt of negatives,
        # slow progress) on small samples; the result is checked below instead.
        warnings.simplefilter("ignore", RuntimeWarning)
        alpha, beta_, _, _ = beta_dist.fit(scaled, floc=0, fscale=1, method="MM")
    return float(alpha), float(beta_)


def fit_profile(values: Iterable[float] | np.ndarray) -> Profile:
    """Fit the scene profile to per-image complexity values, exactly as the official code.

    Args:
        values: per-image complexities; NaN and infinite entries are dropped with a warning.

    Returns:
        The :class:`Profile`. With no finite value every field is NaN; with one value, or all values
        equal, mu/a/b are that value, sigma is 0 and alpha/beta are NaN (a Beta cannot be fitted to
        a point). Each of these cases warns with :class:`DegenerateProfileWarning`.
    """
    arr = np.asarray(list(values) if not isinstance(values, np.ndarray) else values, np.float64)
    arr = arr.reshape(-1)
    finite = arr[np.isfinite(arr)]
    if 0 < finite.size < arr.size:
        warnings.warn(
            f"{arr.size - finite.size} of {arr.size} values are NaN or infinite "
            "(unreadable images); they are left out of the profile",
            DegenerateProfileWarning,
            stacklevel=2,
        )
    if finite.size == 0:
        warnings.warn(
            f"no finite complexity values (of {arr.size}): the profile is undefined (all NaN)",
            DegenerateProfileWarning,
            stacklevel=2,
        )
        nan = math.nan
        return Profile(nan, nan, nan, nan, nan, nan, n=0)
    mu = float(finite.mean())
    sigma = float(finite.std())
    a = float(finite.min())
    b = float(finite.max())
    if b == a:
        warnings.warn(
            f"all {finite.size} values equal {a!r}: a Beta distribution cannot be fitted to a "
            "single point, so alpha and beta are NaN",
            DegenerateProfileWarning,
            stacklevel=2,
        )
        return Profile(mu, 0.0, math.nan, math.nan, a, b, n=int(finite.size))
    scaled = np.clip((finite - a) / (b - a), EPS, 1 - EPS)
    alpha, beta_ = _beta_mm(scaled)
    if not (math.isfinite(alpha) and math.isfinite(beta_) and alpha > 0 and beta_ > 0):
        warnings.warn(
            f"the Beta moment fit failed on {finite.size} values (alpha={alpha}, beta={beta_}); "
            "alpha and beta are NaN",
            DegenerateProfileWarning,
            stacklevel=2,
        )
        alpha = beta_ = math.nan
    return Profile(mu, sigma, alpha, beta_, a, b, n=int(finite.size))
