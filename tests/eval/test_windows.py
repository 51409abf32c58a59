"""Sliding-window inference: coverage, averaging, padding, scale, any model type."""

import numpy as np
import pytest
import torch

from claravid.eval.windows import WindowConfig, predict_labels, sliding_window_logits, window_starts


def test_window_starts_cover_the_axis_with_the_last_flush():
    assert window_starts(10, 4, 3) == [0, 3, 6]
    assert window_starts(11, 4, 3) == [0, 3, 6, 7]
    assert window_starts(4, 4, 3) == [0]
    assert window_starts(3, 4, 3) == [0]


def _pointwise(weight: torch.Tensor):
    """A 1×1-conv model: its logits at a pixel depend on that pixel only."""
    return lambda x: torch.einsum("kc,bchw->bkhw", weight, x)


def test_pointwise_model_equals_the_full_image_forward():
    torch.manual_seed(0)
    weight = torch.randn(5, 3)
    image = torch.randn(3, 37, 53)
    config = WindowConfig(size=(14, 14), stride=(9, 9), batch_size=3)
    out = sliding_window_logits(_pointwise(weight), image, config)
    np.testing.assert_allclose(out, _pointwise(weight)(image[None])[0], atol=1e-5)


def test_overlapping_windows_are_averaged():
    """A model that returns the window's index as its logit: overlaps give the mean index."""
    seen = []

    def counter(x):
        out = torch.empty(x.shape[0], 1, *x.shape[-2:])
        for i in range(x.shape[0]):
            out[i] = len(seen)
            seen.append(1)
        return out

    # One row of width 10, windows of 4 every 3: starts 0, 3, 6 -> indices 0, 1, 2.
    out = sliding_window_logits(
        counter, torch.zeros(3, 4, 10), WindowConfig(size=(4, 4), stride=(3, 3), batch_size=2)
    )[0, 0]
    # columns 0-2: window 0 only; 3: windows 0,1; 4-5: 1; 6: 1,2; 7-9: 2.
    expected = [0, 0, 0, 0.5, 1, 1, 1.5, 2, 2, 2]
    np.testing.assert_allclose(out, expected)


def test_small_images_are_padded_and_cut_back():
    shapes = []

    def model(x):
        shapes.append(tuple(x.shape))
        return x[:, :2]

    image = torch.randn(3, 5, 7)
    out = sliding_window_logits(model, image, WindowConfig(size=(14, 14)))
    assert shapes == [(1, 3, 14, 14)]  # the model always sees a full window
    np.testing.assert_allclose(out, image[:2])


def test_scale_resizes_and_logits_come_back_at_full_size():
    sizes = []

    def model(x):
        sizes.extend([tuple(x.shape[-2:])] * x.shape[0])
        return x[:, :1] * 0 + 1

    out = sliding_window_logits(model, torch.randn(3, 40, 60), WindowConfig(size=14, scale=0.5))
    assert all(s == (14, 14) for s in sizes)
    assert out.shape == (1, 40, 60)
    # The image the windows cut was 20×30: windows of 14 every 9 -> 2 rows × 3 columns.
    assert len(sizes) == 2 * 3
    np.testing.assert_allclose(out, 1.0)


def test_numpy_models_work_and_labels_are_the_argmax():
    weight = torch.tensor([[1.0, 0, 0], [0, 1.0, 0]])
    image = torch.randn(3, 20, 20)
    labels = predict_labels(
        lambda x: _pointwise(weight)(x).numpy(), image, WindowConfig(size=(14, 14))
    )
    np.testing.assert_array_equal(labels, (image[1] > image[0]).long())


def test_matches_a_real_segmenter_within_one_window():
    """Inside one window, the windowed logits are the segmenter's own forward."""
    from claravid import models

    model = models.build_model(
        "dinov2_vits14",
        num_classes=3,
        backbone_kwargs={"embed_dim": 32, "depth": 4, "num_heads": 2},
        layers=[0, 1, 2, 3],
        features=8,
        out_channels=[8, 8, 8, 8],
    ).eval()
    image = torch.randn(3, 28, 42)
    out = sliding_window_logits(model, image, WindowConfig(size=(28, 42)))
    with torch.no_grad():
        np.testing.assert_allclose(out, model(image[None])[0], atol=1e-5)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"size": 0}, "positive integer"), ({"size": (14, 14), "stride": (20, 20)}, "skip pixels"),
     ({"scale": 0}, "scale"), ({"scale": float("nan")}, "scale"), ({"batch_size": 0}, "batch")],
)  # fmt: skip
def test_bad_window_settings(kwargs, message):
    with pytest.raises(ValueError, match=message):
        WindowConfig(**kwargs)


def test_window_not_a_patch_multiple_names_the_fix():
    with pytest.raises(ValueError, match="use 630x630"):
        WindowConfig(size=(640, 640)).check_patch(14)


def test_bad_image():
    with pytest.raises(ValueError, match=r"\[3,H,W\]"):
        sliding_window_logits(lambda x: x, torch.zeros(3, 8, 8, dtype=torch.uint8))
