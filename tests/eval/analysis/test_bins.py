"""Quantile and fixed-edge complexity bins (docs/evaluation.md), edge cases included."""

import pytest

from claravid.eval.analysis.bins import fixed_bins, parse_edges, quantile_bins


def test_quantile_bins_split_like_array_split_in_value_order():
    values = [5.0, 1.0, 4.0, 2.0, 7.0, 3.0, 6.0]
    paths = [f"img{i}" for i in range(7)]
    bins = quantile_bins(values, paths, 3)
    # Sorted by value: 1(i1) 2(i3) 3(i5) | 4(i2) 5(i0) | 6(i6) 7(i4): sizes 3, 2, 2.
    assert [b.name for b in bins] == ["low", "medium", "high"]
    assert [b.indices for b in bins] == [(1, 3, 5), (2, 0), (6, 4)]
    assert [(b.lo, b.hi) for b in bins] == [(1.0, 3.0), (4.0, 5.0), (6.0, 7.0)]


def test_ties_are_broken_by_path_not_by_listing_order():
    values = [2.0, 2.0, 2.0, 1.0]
    bins = quantile_bins(values, ["c", "a", "b", "z"], 2)
    assert [b.indices for b in bins] == [(3, 1), (2, 0)]  # 1.0 first, then a, b, c


def test_one_bin_and_too_many_bins():
    (only,) = quantile_bins([3.0, 1.0], ["a", "b"], 1)
    assert only.name == "all" and only.indices == (1, 0)
    with pytest.raises(ValueError, match="3 bins for 2 images"):
        quantile_bins([3.0, 1.0], ["a", "b"], 3)
    with pytest.raises(ValueError, match="at least 1"):
        quantile_bins([3.0], ["a"], 0)
    with pytest.raises(ValueError, match="NaN"):
        quantile_bins([float("nan")], ["a"], 1)


def test_fixed_edges_half_open_last_closed_empty_bins_kept():
    values = [4.0, 4.5, 5.0, 6.0, 3.9, 6.1]
    bins, outside = fixed_bins(values, [4.0, 4.5, 5.0, 6.0])
    assert [b.name for b in bins] == ["[4, 4.5)", "[4.5, 5)", "[5, 6]"]
    # 4.5 sits on an edge: it starts the second bin; 6.0 is the closed end of the last.
    assert [b.indices for b in bins] == [(0,), (1,), (2, 3)]
    assert outside == [4, 5]
    bins, outside = fixed_bins([1.0, 1.2], [0, 1, 2, 3])
    assert [len(b.indices) for b in bins] == [0, 2, 0]
    assert outside == []


@pytest.mark.parametrize(
    ("text", "message"),
    [("4,4", "strictly increasing"), ("5,4", "strictly increasing"), ("4", "at least 2"),
     ("4,x", "not numbers"), ("4,inf", "finite")],
)  # fmt: skip
def test_bad_edges(text, message):
    with pytest.raises(ValueError, match=message):
        parse_edges(text)
