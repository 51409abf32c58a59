"""The profile against scipy directly, and every degenerate input."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy import integrate
from scipy.stats import beta

from claravid.dsp import DegenerateProfileWarning, Profile, fit_profile, plot_profile


def test_profile_equals_official_recipe_with_scipy():
    values = np.random.default_rng(0).beta(2.5, 4.0, 500) * 2 + 3.9
    prof = fit_profile(values)
    lo, hi = values.min(), values.max()
    scaled = np.clip((values - lo) / (hi - lo), 1e-6, 1 - 1e-6)
    alpha, beta_, loc, scale = beta.fit(scaled, floc=0, fscale=1, method="MM")
    assert (loc, scale) == (0, 1)
    assert prof.alpha == alpha and prof.beta == beta_
    assert prof.mu == np.mean(values) and prof.sigma == np.std(values)  # population sigma
    assert (prof.a, prof.b, prof.n) == (lo, hi, 500)
    # Method of moments in closed form: scipy's solver lands on it.
    m, v = scaled.mean(), scaled.var()
    common = m * (1 - m) / v - 1
    assert prof.alpha == pytest.approx(m * common, rel=1e-4)
    assert prof.beta == pytest.approx((1 - m) * common, rel=1e-4)


def test_pdf_is_a_density_on_the_value_axis():
    prof = fit_profile(np.random.default_rng(1).normal(4.0, 0.1, 300))
    area, _ = integrate.quad(lambda x: float(prof.pdf(np.array(x))), prof.a, prof.b)
    assert area == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize(
    "values,match",
    [
        ([4.2], "all 1 values equal"),
        ([3.0, 3.0, 3.0], "all 3 values equal"),
    ],
)
def test_single_or_equal_values_warn_and_give_nan_shapes(values, match):
    with pytest.warns(DegenerateProfileWarning, match=match):
        prof = fit_profile(values)
    assert prof.mu == values[0] and prof.sigma == 0.0 and prof.a == prof.b == values[0]
    assert math.isnan(prof.alpha) and math.isnan(prof.beta)
    assert prof.to_dict()["alpha"] is None


def test_nans_are_dropped_with_a_warning():
    values = [4.0, float("nan"), 4.5, 5.0, float("inf"), 4.2]
    with pytest.warns(DegenerateProfileWarning, match="2 of 6 values are NaN"):
        prof = fit_profile(values)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        clean = fit_profile([4.0, 4.5, 5.0, 4.2])
    assert prof == clean


@pytest.mark.parametrize("values", [[], [float("nan")] * 3])
def test_no_value_gives_all_nan(values):
    with pytest.warns(DegenerateProfileWarning, match="no finite"):
        prof = fit_profile(values)
    assert prof.n == 0 and all(v is None for v in prof.to_dict().values())


def test_dict_round_trip_and_missing_keys():
    prof = fit_profile([1.0, 2.0, 2.5, 4.0])
    assert Profile.from_dict(prof.to_dict(), n=4) == prof
    with pytest.raises(ValueError, match="missing beta"):
        Profile.from_dict({"mu": 1, "sigma": 1, "alpha": 1, "a": 0, "b": 1})


def test_plot_draws_histogram_fit_and_mu(tmp_path):
    values = np.random.default_rng(2).normal(4.0, 0.2, 200)
    prof = fit_profile(values)
    fig = plot_profile(values, prof, tmp_path / "p.png", title="urban_1")
    ax = fig.axes[0]
    assert ax.get_title() == "urban_1"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert f"α={prof.alpha:.2f}" in labels[0] and f"σ={prof.sigma:.2f}" in labels[0]
    assert ax.lines[1].get_xdata()[0] == pytest.approx(prof.mu)  # the mu line
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.warns(DegenerateProfileWarning):
        plot_profile([4.0], None, tmp_path / "one.png")  # degenerate still draws
    assert (tmp_path / "one.png").exists()
