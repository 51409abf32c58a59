"""Calibration sums against torchmetrics' MulticlassCalibrationError on the same probabilities."""

from fractions import Fraction

import numpy as np
import pytest
import torch
from torchmetrics.classification import MulticlassCalibrationError

from claravid.eval.analysis.calibration import calibration_errors, reliability
from claravid.eval.measures import calibration_sums as calibration
from claravid.eval.measures.calibration_sums import bin_edges, calibration_bins, calibration_sums


def softmax_scores(rng, k, shape, sharpness):
    """Probabilities [K, H, W] of a made-up model: some sharp, some flat pixels, some wrong."""
    logits = rng.normal(0, 1, (k, *shape)) * rng.uniform(0.2, sharpness, shape)
    return torch.softmax(torch.from_numpy(logits).float(), dim=0)


def labels_near(probs, rng, right=0.7):
    """Ground truth that agrees with the argmax on about ``right`` of the pixels."""
    k = probs.shape[0]
    pred = probs.argmax(0).numpy()
    other = rng.integers(0, k, pred.shape)
    return np.where(rng.random(pred.shape) < right, pred, other).astype(np.uint8)


#: The C pass eight pixels at a time (AVX2, where the CPU has it), the C pass one pixel at a
#: time, and numpy.
PATHS = ["C", "C one by one", "numpy"]


def use(monkeypatch, path):
    if path == "numpy":
        monkeypatch.setattr(calibration, "_native", None)
    elif path == "C one by one":
        monkeypatch.setattr(calibration, "_vector", False)


def exact_sums(conf, gt, edges):
    """Per bin, the exact sum of the confidences (fractions), rounded once to float64."""
    bins = len(edges) - 1
    out = [Fraction(0)] * bins
    for c, t in zip(conf.ravel(), gt.ravel(), strict=True):
        if t != 255:
            b = min(int(np.sum(edges[1:] <= c)), bins - 1)
            out[b] += Fraction(float(c))
    return np.array([float(f) for f in out])


def torchmetrics_errors(probs, gt, n_bins):
    """ECE and MCE from torchmetrics on the pixels whose ground truth is not ignored."""
    k = probs.shape[0]
    flat = probs.reshape(k, -1).T
    target = torch.from_numpy(gt.reshape(-1).astype(np.int64))
    keep = target != 255
    out = []
    for norm in ("l1", "max"):
        metric = MulticlassCalibrationError(num_classes=k, n_bins=n_bins, norm=norm)
        out.append(float(metric(flat[keep], target[keep])))
    return out


@pytest.mark.parametrize(
    ("k", "shape", "n_bins", "sharpness"),
    [(8, (37, 53), 15, 6.0), (19, (24, 40), 15, 7.0), (3, (31, 17), 10, 3.0), (5, (9, 64), 1, 4.0)],
)
@pytest.mark.parametrize("path", PATHS)
def test_ece_and_mce_match_torchmetrics(monkeypatch, path, k, shape, n_bins, sharpness):
    use(monkeypatch, path)
    rng = np.random.default_rng(k * 100 + n_bins)
    probs = softmax_scores(rng, k, shape, sharpness)
    assert probs.max() < 1.0  # exactly 1.0 is binned differently by torchmetrics (see below)
    gt = labels_near(probs, rng)
    gt[rng.random(shape) < 0.1] = 255
    count, conf_sum, correct = calibration_bins(probs.numpy(), gt, n_bins)
    assert count.dtype == np.int64 and correct.dtype == np.int64 and conf_sum.dtype == np.float64
    assert count.shape == (n_bins,) and count.sum() == (gt != 255).sum()
    ece, mce = calibration_errors(count, conf_sum, correct)
    expected_ece, expected_mce = torchmetrics_errors(probs, gt, n_bins)
    assert ece == pytest.approx(expected_ece, abs=1e-6)
    assert mce == pytest.approx(expected_mce, abs=1e-6)


def test_sums_are_the_definition_counted_here():
    """Per bin: count, confidence sum and correct pixels, by a plain loop over the pixels."""
    rng = np.random.default_rng(5)
    probs = softmax_scores(rng, 4, (13, 11), 5.0)
    gt = labels_near(probs, rng)
    gt[0, :5] = 255
    conf, pred = probs.max(0)
    edges = torch.linspace(0, 1, 16).numpy()
    count, conf_sum, correct = np.zeros(15, int), np.zeros(15), np.zeros(15, int)
    for c, p, t in zip(conf.numpy().ravel(), pred.numpy().ravel(), gt.ravel(), strict=True):
        if t == 255:
            continue
        b = min(int(np.sum(edges[1:] <= c)), 14)
        count[b] += 1
        conf_sum[b] += float(c)
        correct[b] += int(p == t)
    got = calibration_bins(probs, torch.from_numpy(gt), 15)
    np.testing.assert_array_equal(got[0], count)
    np.testing.assert_allclose(got[1], conf_sum, rtol=1e-12)
    np.testing.assert_array_equal(got[2], correct)


@pytest.mark.parametrize("path", PATHS)
def test_edges_and_exact_one_go_where_the_docs_say(monkeypatch, path):
    """A confidence on an edge starts that bin ([e_i, e_i+1)); exactly 1.0 is in the last bin."""
    use(monkeypatch, path)
    edges = bin_edges(5)
    conf = np.array([[0.0, edges[1], np.nextafter(edges[1], 0), edges[4], 1.0, 0.5]], np.float32)
    pred = np.zeros(conf.shape, np.uint8)
    gt = np.array([[0, 0, 1, 0, 0, 255]], np.uint8)
    count, conf_sum, correct = calibration_sums(conf, pred, gt, n_bins=5)
    np.testing.assert_array_equal(count, [2, 1, 0, 0, 2])
    np.testing.assert_array_equal(correct, [1, 1, 0, 0, 2])
    assert conf_sum[4] == pytest.approx(float(edges[4]) + 1.0)


@pytest.mark.parametrize("path", PATHS)
def test_confidence_sums_are_exact_whatever_the_confidences(monkeypatch, path):
    """Softmax confidences, tiny ones (a class count past 128), subnormals, 0, -0, values on and
    beside every edge, ignored NaNs: each bin's sum is the exact sum rounded once."""
    use(monkeypatch, path)
    rng = np.random.default_rng(21)
    edges = bin_edges(15)
    near_edges = np.concatenate([edges, np.nextafter(edges, -1), np.nextafter(edges, 2)])
    special = [0.0, -0.0, 1e-45, 3e-39, 1e-30, 2.0**-7, np.nextafter(2.0**-7, 0), 1e-3, 1.0]
    conf = np.concatenate([
        softmax_scores(rng, 6, (1, 900), 9.0).max(0).values.numpy().ravel(),
        rng.uniform(0, 0.01, 300), np.clip(near_edges, -0.0, 1.0), special * 3,
    ]).astype(np.float32)  # fmt: skip
    rng.shuffle(conf)
    conf = np.resize(conf, (37, 45))  # 1665 pixels: not a multiple of eight
    gt = rng.integers(0, 3, conf.shape).astype(np.uint8)
    gt[rng.random(conf.shape) < 0.1] = 255
    conf[(gt == 255) & (rng.random(conf.shape) < 0.3)] = np.nan  # ignored: never looked at
    pred = rng.integers(0, 3, conf.shape).astype(np.uint8)
    count, conf_sum, correct = calibration_sums(conf, pred, gt)
    np.testing.assert_array_equal(conf_sum, exact_sums(conf, gt, edges))
    assert count.sum() == (gt != 255).sum() and correct.sum() == ((pred == gt) & (gt != 255)).sum()
    # Only subnormals and tiny normals in bin 0: their own exponents, nothing to round them away.
    tiny = np.array([[1e-45, 3e-39, 0.0, 2e-38, 1.2e-38, 5e-30, 1e-39, 7e-45, 0.0]], np.float32)
    labels = np.zeros(tiny.shape, np.uint8)
    _, conf_sum, _ = calibration_sums(tiny, labels, labels)
    np.testing.assert_array_equal(conf_sum, exact_sums(tiny, labels, edges))


def test_the_c_pass_and_numpy_agree_to_the_bit(monkeypatch):
    if calibration._native is None:
        pytest.skip("the optional C module is not built here")
    rng = np.random.default_rng(11)
    probs = softmax_scores(rng, 7, (64, 96), 8.0)
    probs[:, :3] = torch.nn.functional.one_hot(torch.zeros(3, 96).long(), 7).permute(2, 0, 1)
    gt = labels_near(probs, rng)
    gt[rng.random(gt.shape) < 0.2] = 255
    native = calibration_bins(probs, gt)
    monkeypatch.setattr(calibration, "_vector", False)
    for a, b in zip(native, calibration_bins(probs, gt), strict=True):
        np.testing.assert_array_equal(a, b)
    monkeypatch.setattr(calibration, "_vector", True)
    # Confidences on, just below and just above every edge, 0, -0, 1 and the smallest floats:
    # the C pass's table of bit patterns must bin them as the edges say.
    edges = bin_edges(15)
    tricky = np.concatenate([edges, np.nextafter(edges, -1), np.nextafter(edges, 2)])
    tricky = np.clip(np.concatenate([tricky, [0.0, -0.0, 1e-45, 1e-38, 0.5]]), -0.0, 1.0)
    conf = np.resize(tricky.astype(np.float32), (9, 13))
    pred, truth = np.zeros((9, 13), np.uint8), (np.arange(117).reshape(9, 13) % 3).astype(np.uint8)
    native_edges = calibration_sums(conf, pred, truth)
    monkeypatch.setattr(calibration, "_native", None)
    plain = calibration_bins(probs, gt)
    for a, b in zip(native, plain, strict=True):
        np.testing.assert_array_equal(a, b)
    assert native[0][-1] >= 3 * 96 * 0.7  # the saturated rows (confidence 1.0): the last bin
    for a, b in zip(native_edges, calibration_sums(conf, pred, truth), strict=True):
        np.testing.assert_array_equal(a, b)


def test_reliability_and_empty_groups():
    confidence, accuracy, share = reliability([2, 0, 2], [0.4, 0.0, 1.8], [1, 0, 2])
    np.testing.assert_allclose(confidence, [0.2, np.nan, 0.9])
    np.testing.assert_allclose(accuracy, [0.5, np.nan, 1.0])
    np.testing.assert_allclose(share, [0.5, 0.0, 0.5])
    ece, mce = calibration_errors([2, 0, 2], [0.4, 0.0, 1.8], [1, 0, 2])
    assert ece == pytest.approx((0.6 + 0.2) / 4) and mce == pytest.approx(0.3)
    assert all(np.isnan(calibration_errors([0, 0], [0.0, 0.0], [0, 0])))


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize(
    ("probs", "gt", "match"),
    [
        (
            np.full((3, 4, 5), 2.0, np.float32),
            np.zeros((4, 5), int),
            "not in \\[0, 1\\]: pass prob",
        ),
        (np.full((3, 4, 5), np.nan, np.float32), np.zeros((4, 5), int), "nan at pixel 0"),
        (np.full((3, 4, 5), 0.3, np.float32), np.full((4, 5), 3), r"ground truth holds ids \[3\]"),
        (np.full((3, 4, 5), 0.3, np.float32), np.zeros((5, 4), int), "differ in shape"),
        (np.full((4, 5), 0.3, np.float32), np.zeros((4, 5), int), r"\[K, H, W\] class prob"),
        (np.zeros((3, 4, 5), int), np.zeros((4, 5), int), "floating point"),
    ],
)
def test_bad_inputs_say_what_is_wrong(monkeypatch, path, probs, gt, match):
    use(monkeypatch, path)
    with pytest.raises(ValueError, match=match):
        calibration_bins(probs, gt)


def test_bad_bin_counts():
    with pytest.raises(ValueError, match="n_bins must be a positive integer"):
        bin_edges(0)
