"""Calibration sums against torchmetrics' MulticlassCalibrationError on the same probabilities."""

from fractions import Fraction

import numpy as np
import pytest
import torch
from torchmetrics.classification import MulticlassCalibrationError

from claravid.eval.analysis.calibration import calibration_errors, reliability
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


#: Where the sums are counted: torch (the inputs as tensors, on the CPU here; on a GPU in
#: test_the_sums_on_a_gpu_are_numpys) and numpy.
PATHS = ["torch", "numpy"]


def on(path, *arrays):
    """The arrays as the path takes them: tensors for torch, numpy arrays for numpy."""
    if path == "numpy":
        return [a.numpy() if isinstance(a, torch.Tensor) else np.asarray(a) for a in arrays]
    return [a if isinstance(a, torch.Tensor) else torch.from_numpy(np.asarray(a)) for a in arrays]


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
def test_ece_and_mce_match_torchmetrics(path, k, shape, n_bins, sharpness):
    rng = np.random.default_rng(k * 100 + n_bins)
    probs = softmax_scores(rng, k, shape, sharpness)
    assert probs.max() < 1.0  # exactly 1.0 is binned differently by torchmetrics (see below)
    gt = labels_near(probs, rng)
    gt[rng.random(shape) < 0.1] = 255
    count, conf_sum, correct = calibration_bins(*on(path, probs, gt), n_bins)
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
def test_edges_and_exact_one_go_where_the_docs_say(path):
    """A confidence on an edge starts that bin ([e_i, e_i+1)); exactly 1.0 is in the last bin."""
    edges = bin_edges(5)
    conf = np.array([[0.0, edges[1], np.nextafter(edges[1], 0), edges[4], 1.0, 0.5]], np.float32)
    pred = np.zeros(conf.shape, np.uint8)
    gt = np.array([[0, 0, 1, 0, 0, 255]], np.uint8)
    count, conf_sum, correct = calibration_sums(*on(path, conf, pred, gt), n_bins=5)
    np.testing.assert_array_equal(count, [2, 1, 0, 0, 2])
    np.testing.assert_array_equal(correct, [1, 1, 0, 0, 2])
    assert conf_sum[4] == pytest.approx(float(edges[4]) + 1.0)


@pytest.mark.parametrize("path", PATHS)
def test_confidence_sums_are_exact_whatever_the_confidences(path):
    """Softmax confidences, tiny ones (a class count past 128), subnormals, 0, -0, values on and
    beside every edge, ignored NaNs: each bin's sum is the exact sum rounded once."""
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
    count, conf_sum, correct = calibration_sums(*on(path, conf, pred, gt))
    np.testing.assert_array_equal(conf_sum, exact_sums(conf, gt, edges))
    assert count.sum() == (gt != 255).sum() and correct.sum() == ((pred == gt) & (gt != 255)).sum()
    # Only subnormals and tiny normals in bin 0: their own exponents, nothing to round them away.
    tiny = np.array([[1e-45, 3e-39, 0.0, 2e-38, 1.2e-38, 5e-30, 1e-39, 7e-45, 0.0]], np.float32)
    labels = np.zeros(tiny.shape, np.uint8)
    _, conf_sum, _ = calibration_sums(*on(path, tiny, labels, labels))
    np.testing.assert_array_equal(conf_sum, exact_sums(tiny, labels, edges))


def by_hand(conf, pred, gt, edges):
    """Count, exact confidence sum and correct pixels per bin, pixel by pixel: a pixel's bin is
    the number of inner edges it reaches (1.0 thus in the last)."""
    bins = len(edges) - 1
    count, correct = np.zeros(bins, np.int64), np.zeros(bins, np.int64)
    for c, p, t in zip(conf.ravel().tolist(), pred.ravel().tolist(), gt.ravel().tolist(),
                       strict=True):  # fmt: skip
        if t != 255:
            b = sum(c >= float(e) for e in edges[1:-1])
            count[b] += 1
            correct[b] += p == t
    return count, exact_sums(conf, gt, edges), correct


def around_edges(n_bins, ulps):
    """Every float32 within ``ulps`` steps of each edge of ``n_bins`` bins, in [0, 1], with 0,
    -0, the smallest subnormal and 2^-7's neighbours."""
    bits = (bin_edges(n_bins).view(np.int32)[:, None] + np.arange(-ulps, ulps + 1)).ravel()
    bits = np.unique(np.clip(bits, 0, np.float32(1).view(np.int32)))  # [0, 1]: no NaN patterns
    values = bits.astype(np.int32).view(np.float32)
    special = [0.0, -0.0, 1e-45, np.nextafter(np.float32(2.0**-7), 0), 2.0**-7, 1.0]
    return np.concatenate([values, np.array(special, np.float32)])


#: Bin counts, each with a non-square image size.
EDGE_CASES = [(1, (3, 7)), (3, (5, 11)), (10, (7, 13)), (15, (9, 31)), (19, (11, 17)),
              (100, (23, 41))]  # fmt: skip


@pytest.mark.parametrize(("n_bins", "shape"), EDGE_CASES)
def test_torch_and_numpy_agree_to_the_bit_around_every_edge(n_bins, shape):
    """Every float32 within 64 steps of every edge (both sides; 8 for 100 bins), non-square
    images: torch and numpy give the same integers and float64 sums, and both are the
    pixel-by-pixel count."""
    rng = np.random.default_rng(n_bins)
    values = around_edges(n_bins, min(64, 800 // n_bins))
    size = shape[0] * shape[1]
    for start in range(0, len(values), size):
        conf = np.resize(np.roll(values, -start), shape)
        gt = rng.integers(0, 3, shape).astype(np.uint8)
        gt[rng.random(shape) < 0.1] = 255
        pred = rng.integers(0, 3, shape).astype(np.uint8)
        numpy_sums = calibration_sums(conf, pred, gt, n_bins)
        torch_sums = calibration_sums(*on("torch", conf, pred, gt), n_bins)
        for a, b, c in zip(numpy_sums, torch_sums, by_hand(conf, pred, gt, bin_edges(n_bins)),
                           strict=True):  # fmt: skip
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
            np.testing.assert_array_equal(a, c)


@pytest.mark.parametrize(("k", "shape", "n_bins"), [(7, (64, 96), 15), (19, (45, 31), 10),
                                                     (200, (13, 29), 7)])  # fmt: skip
def test_torch_and_numpy_agree_to_the_bit_on_random_maps(k, shape, n_bins):
    """Softmax maps (200 classes: confidences under 2^-7), saturated rows (1.0) and ignored
    pixels: the same integers, the same float64 bits."""
    rng = np.random.default_rng(k)
    probs = softmax_scores(rng, k, shape, 8.0)
    probs[:, :3] = torch.nn.functional.one_hot(torch.zeros(3, shape[1]).long(), k).permute(2, 0, 1)
    gt = labels_near(probs, rng)
    gt[rng.random(gt.shape) < 0.2] = 255
    numpy_sums = calibration_bins(probs.numpy(), gt, n_bins)
    torch_sums = calibration_bins(probs, torch.from_numpy(gt), n_bins)
    for a, b in zip(numpy_sums, torch_sums, strict=True):
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()
    assert numpy_sums[0][-1] >= 3 * shape[1] * 0.7  # the saturated rows: the last bin


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU here")
def test_the_sums_on_a_gpu_are_numpys():
    """The confidences counted where a model on a GPU leaves them: numpy's numbers to the bit."""
    rng = np.random.default_rng(3)
    probs = softmax_scores(rng, 19, (301, 403), 8.0)
    gt = labels_near(probs, rng)
    gt[rng.random(gt.shape) < 0.1] = 255
    edge_values = np.resize(around_edges(15, 256), (59, 131))
    edge_labels = rng.integers(0, 3, edge_values.shape).astype(np.uint8)
    for scores, truth in ((probs, gt), (None, None)):
        if scores is None:  # every float32 near the edges, as a map of confidences
            conf, pred = torch.from_numpy(edge_values), torch.from_numpy(edge_labels)
            truth = edge_labels[::-1].copy()
            expected = calibration_sums(conf.numpy(), pred.numpy(), truth)
            got = calibration_sums(conf.cuda(), pred.cuda(), torch.from_numpy(truth).cuda())
        else:
            expected = calibration_bins(scores.numpy(), truth)
            got = calibration_bins(scores.cuda(), torch.from_numpy(truth).cuda())
        for a, b in zip(expected, got, strict=True):
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes()


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
def test_bad_inputs_say_what_is_wrong(path, probs, gt, match):
    with pytest.raises(ValueError, match=match):
        calibration_bins(*on(path, probs, gt))


def test_bad_bin_counts():
    with pytest.raises(ValueError, match="n_bins must be a positive integer"):
        bin_edges(0)
