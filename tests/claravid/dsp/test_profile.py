"""The profile against scipy directly, and every degenerate input."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy import integrate
from scipy.stats import beta

from claravid.dsp import DegenerateProfileWarning, Profile, fit_profile, plot_profile

from .reference_profile import moments_beta, official_profile


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


def test_hand_computed_profile_of_four_values():
    """Worked by hand: H = 4, 5, 6, 9 -> mu 6, sigma sqrt(3.5), scaled 0, .2, .4, 1 (clipped)."""
    prof = fit_profile([4.0, 5.0, 6.0, 9.0])
    assert (prof.mu, prof.a, prof.b, prof.n) == (6.0, 4.0, 9.0, 4)
    assert prof.sigma == pytest.approx(math.sqrt(3.5), rel=1e-12)  # population, not sqrt(14/3)
    # Scaled values 0, .2, .4, 1 (clipped by 1e-6): m = 0.4, v = (.16 + .04 + 0 + .36) / 4 = 0.14,
    # c = m (1 - m) / v - 1 = 5/7, so alpha = m c = 2/7 and beta = (1 - m) c = 3/7.
    assert prof.alpha == pytest.approx(2 / 7, rel=1e-4)
    assert prof.beta == pytest.approx(3 / 7, rel=1e-4)
    assert (prof.alpha, prof.beta) == pytest.approx(moments_beta([4, 5, 6, 9]), rel=1e-4)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_profile_matches_the_independent_recipe(seed):
    rng = np.random.default_rng(seed)
    values = rng.beta(1.5 + seed, 3.0, 50 + 100 * seed) * 1.5 + 3.5
    expected = official_profile(values)
    got = fit_profile(values).to_dict()
    assert list(got) == list(expected)
    for key in expected:
        assert got[key] == pytest.approx(expected[key], rel=1e-12), key


def test_pdf_is_a_density_on_the_value_axis():
    values = np.random.default_rng(1).normal(4.0, 0.1, 300)
    prof = fit_profile(values)
    area, _ = integrate.quad(lambda x: float(prof.pdf(np.array(x))), prof.a, prof.b)
    assert area == pytest.approx(1.0, abs=1e-6)
    # Pointwise: the Beta density of the scaled value, divided by the range (change of variable).
    ref = official_profile(values)
    assert ref["alpha"] != pytest.approx(ref["beta"], rel=0.05)  # a swap would show
    span = ref["b"] - ref["a"]
    x = ref["a"] + span * np.array([0.1, 0.3, 0.5, 0.7, 0.9])
    expected = beta.pdf((x - ref["a"]) / span, ref["alpha"], ref["beta"]) / span
    np.testing.assert_allclose(prof.pdf(x), expected, rtol=1e-9)


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
        warnings.simplefilter("error")  # finite values alone: no warning
        clean = fit_profile([4.0, 4.5, 5.0, 4.2])
    assert prof == clean and prof.n == 4
    assert prof.to_dict() == pytest.approx(official_profile([4.0, 4.5, 5.0, 4.2]), rel=1e-12)
    # By hand: mean 17.7 / 4; squared deviations .180625 + .005625 + .330625 + .050625 = .5675.
    assert prof.mu == pytest.approx(4.425) and prof.sigma == pytest.approx(math.sqrt(0.141875))


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
    ref = official_profile(values)
    fig = plot_profile(values, prof, tmp_path / "p.png", title="urban_1")
    ax = fig.axes[0]
    assert ax.get_title() == "urban_1"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    for symbol, key in (("α", "alpha"), ("β", "beta"), ("μ", "mu"), ("σ", "sigma")):
        assert f"{symbol}={ref[key]:.2f}" in labels[0], (symbol, labels[0])
    assert ax.lines[1].get_xdata()[0] == pytest.approx(np.mean(values))  # the mu line
    assert len(ax.patches) > 5  # the histogram's bars
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.warns(DegenerateProfileWarning):
        plot_profile([4.0], None, tmp_path / "one.png")  # degenerate still draws
    assert (tmp_path / "one.png").exists()
