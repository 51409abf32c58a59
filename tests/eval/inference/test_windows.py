"""Sliding-window inference: coverage, averaging, padding, scale, any model type."""

import re

import numpy as np
import pytest
import torch

from claravid import models
from claravid.eval.inference.windows import (
    WindowConfig,
    predict_labels,
    sliding_window_logits,
    window_starts,
)
from claravid.infra.precision import flag_precision
from tests.tiny import MODEL


def test_window_starts_cover_the_axis_with_the_last_flush():
    assert window_starts(10, 4, 3) == [0, 3, 6]
    assert window_starts(11, 4, 3) == [0, 3, 6, 7]
    assert window_starts(4, 4, 3) == [0]
    assert window_starts(3, 4, 3) == [0]


def _normalised_noise(*shape: int) -> torch.Tensor:
    """Standard normal values clamped to what ImageNet normalisation gives every channel
    ([-1.80, 2.25] lies in each): normalise refuses float images outside that range."""
    return torch.randn(*shape).clamp(-1.8, 2.2)


def _pointwise(weight: torch.Tensor):
    """A 1×1-conv model: its logits at a pixel depend on that pixel only."""
    return lambda x: torch.einsum("kc,bchw->bkhw", weight, x)


def test_pointwise_model_equals_the_full_image_forward():
    torch.manual_seed(0)
    weight = torch.randn(5, 3)
    image = _normalised_noise(3, 37, 53)
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


def _window_index_model():
    """A model whose logits are the index of the window (in the order it was given), and the
    index squared: a pixel's averaged logits tell which windows covered it."""
    seen = []

    def model(x):
        out = torch.empty(x.shape[0], 2, *x.shape[-2:])
        for i in range(x.shape[0]):
            out[i, 0], out[i, 1] = len(seen), len(seen) ** 2
            seen.append(tuple(x.shape[-2:]))
        return out

    return model, seen


@pytest.mark.parametrize(
    ("image_hw", "window_hw", "stride_hw", "rows", "cols"),
    [
        # Tall windows (12 high, 4 wide) whose vertical step (6) is more than their width.
        ((20, 11), (12, 4), (6, 3), [0, 6, 8], [0, 3, 6, 7]),
        # Wide windows (4 high, 12 wide) whose horizontal step (6) is more than their height.
        ((11, 20), (4, 12), (3, 6), [0, 3, 6, 7], [0, 6, 8]),
    ],
)
def test_non_square_windows_and_strides_cover_every_pixel(
    image_hw, window_hw, stride_hw, rows, cols
):
    """Starts written out by hand (every step, the last window flush with the border); each
    pixel's logits are the mean of the indices of the windows that cover it, built here."""
    model, seen = _window_index_model()
    config = WindowConfig(size=window_hw, stride=stride_hw, batch_size=5)
    out = sliding_window_logits(model, torch.zeros(3, *image_hw), config).numpy()
    (h, w), (wh, ww) = image_hw, window_hw
    assert seen == [window_hw] * (len(rows) * len(cols))  # every window (height, width)
    total, hits = np.zeros((2, h, w)), np.zeros((h, w))
    for index, (y, x) in enumerate((y, x) for y in rows for x in cols):
        total[0, y : y + wh, x : x + ww] += index
        total[1, y : y + wh, x : x + ww] += index**2
        hits[y : y + wh, x : x + ww] += 1
    assert hits.min() >= 1  # the hand-built windows cover every pixel
    assert np.isfinite(out).all()
    np.testing.assert_allclose(out, total / hits, rtol=1e-6)


def test_small_images_are_padded_and_cut_back():
    shapes = []

    def model(x):
        shapes.append(tuple(x.shape))
        return x[:, :2]

    image = _normalised_noise(3, 5, 7)
    out = sliding_window_logits(model, image, WindowConfig(size=(14, 14)))
    assert shapes == [(1, 3, 14, 14)]  # the model always sees a full window
    np.testing.assert_allclose(out, image[:2])


def test_scale_resizes_and_logits_come_back_at_full_size():
    sizes = []

    def model(x):
        sizes.extend([tuple(x.shape[-2:])] * x.shape[0])
        return x[:, :1] * 0 + 1

    out = sliding_window_logits(
        model, _normalised_noise(3, 40, 60), WindowConfig(size=14, scale=0.5)
    )
    assert all(s == (14, 14) for s in sizes)
    assert out.shape == (1, 40, 60)
    # The image the windows cut was 20×30: windows of 14 every 9 -> 2 rows × 3 columns.
    assert len(sizes) == 2 * 3
    np.testing.assert_allclose(out, 1.0)


def test_numpy_models_work_and_labels_are_the_argmax():
    weight = torch.tensor([[1.0, 0, 0], [0, 1.0, 0]])
    image = _normalised_noise(3, 20, 20)
    labels = predict_labels(
        lambda x: _pointwise(weight)(x).numpy(), image, WindowConfig(size=(14, 14))
    )
    np.testing.assert_array_equal(labels, (image[1] > image[0]).long())


def test_matches_a_real_segmenter_within_one_window():
    """Inside one window, the windowed logits are the segmenter's own forward."""
    from claravid import models

    model = models.build_model("dinov2_vits14", num_classes=3, **MODEL).eval()
    image = _normalised_noise(3, 28, 42)
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


def test_window_not_a_patch_multiple_names_the_two_nearest():
    # 640 = 45.7 x 14: 630 or 644; 630 = 39.4 x 16: 624 or 640.
    with pytest.raises(ValueError, match="use 630x630 or 644x644"):
        WindowConfig(size=(640, 640)).check_patch(14)
    with pytest.raises(ValueError, match="patch size 16: use 624x624 or 640x640"):
        WindowConfig(size=630).check_patch(16)
    # Said as --window takes it, width x height: size is (height 30, width 56); 56 fits.
    message = (
        "window 56x30 (WxH) is not a multiple of the model's patch size 14: use 56x28 or 56x42"
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        WindowConfig(size=(30, 56)).check_patch(14)
    WindowConfig(size=(32, 48)).check_patch(16)  # multiples: nothing to say


def _tiny(backbone):
    torch.manual_seed(0)
    return models.build_model(backbone, 8, **MODEL).eval()


@pytest.mark.parametrize(
    ("backbone", "side", "mean", "std"),
    [
        ("dinov2_vits14", 630, (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)),
        ("dinov3_vits16", 640, (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)),
        ("dinov3_vitl16_sat", 640, (0.430, 0.411, 0.296), (0.213, 0.156, 0.143)),
    ],
)
def test_what_the_config_leaves_unset_is_the_model_s(backbone, side, mean, std):
    """No window: the model's natural size (not a hard 630); no statistics: its own."""
    model = _tiny(backbone)
    config = WindowConfig(scale=0.5).for_model(model)
    assert config.size == (side, side) and config.stride == (side * 2 // 3,) * 2
    assert (config.mean, config.std) == (mean, std) and config.scale == 0.5
    # 112 x 224: multiples of 14 and of 16, one window for either family
    given = WindowConfig(size=(112, 224), mean=(0.5,) * 3, std=(0.25,) * 3).for_model(model)
    assert given.size == (112, 224) and given.mean == (0.5,) * 3  # what is set stays
    # A uint8 image through the windows equals the model fed its own normalisation by hand.
    image = torch.from_numpy(np.random.default_rng(0).integers(0, 256, (3, 112, 224), np.uint8))
    got = sliding_window_logits(model, image, WindowConfig(size=(112, 224)))
    x = (image.float() / 255 - torch.tensor(mean).view(3, 1, 1)) / torch.tensor(std).view(3, 1, 1)
    with torch.no_grad():
        expected = model(x[None])[0]
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-5)


def test_a_model_without_statistics_needs_them_for_uint8_images():
    image = torch.zeros(3, 28, 28, dtype=torch.uint8)
    with pytest.raises(ValueError, match=r"pass WindowConfig\(mean=..., std=...\)"):
        sliding_window_logits(lambda x: x, image, WindowConfig(size=28))
    floats = sliding_window_logits(lambda x: x, image.float(), WindowConfig(size=28))
    assert floats.shape == (3, 28, 28)  # normalised already: no statistics needed


def test_bad_image():
    with pytest.raises(ValueError, match=r"\[3,H,W\]"):
        sliding_window_logits(lambda x: x, torch.zeros(3, 8, 8, dtype=torch.int64))
    with pytest.raises(ValueError, match=r"\[3,H,W\]"):
        sliding_window_logits(lambda x: x, torch.zeros(4, 8, 8, dtype=torch.uint8))


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_uint8_frames_are_normalised_on_the_device_as_eval_transforms_did(scale):
    # The frame travels as uint8 and is normalised where the model runs; the logits equal those
    # of the former path (albumentations normalisation on the CPU, float32 frame) within float
    # rounding. A custom mean/std shows the config's normalisation is the one applied.
    from claravid.data.transforms import augment_config, eval_transforms

    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (3, 61, 83), dtype=np.uint8)
    mean, std = (0.3, 0.5, 0.7), (0.2, 0.25, 0.3)
    model = torch.nn.Conv2d(3, 5, 3, padding=1).eval()
    config = WindowConfig(size=28, scale=scale, mean=mean, std=std)
    old = eval_transforms(augment_config({"mean": list(mean), "std": list(std)}), normalize=True)
    normalised = old({"image": torch.from_numpy(rgb)})["image"]
    expected = sliding_window_logits(model, normalised, config)
    got = sliding_window_logits(model, torch.from_numpy(rgb), config)
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-5)
    imagenet = sliding_window_logits(
        model,
        torch.from_numpy(rgb),
        WindowConfig(size=28, scale=scale, mean=(0.485, 0.456, 0.406), std=(0.229, 0.224, 0.225)),
    )
    assert (imagenet - expected).abs().max() > 0.1  # the mean/std of the config matter


def test_bad_normalisation():
    with pytest.raises(ValueError, match="std must be positive"):
        WindowConfig(mean=(0.5, 0.5, 0.5), std=(0.2, 0.0, 0.3))
    with pytest.raises(ValueError, match="mean must be 3 finite numbers"):
        WindowConfig(mean=(0.5, 0.5), std=(1, 1, 1))


def _reference_at_scale(model, image, scale):
    """The spec restated: resize the image (bilinear, antialiased), run the model on all of it,
    resize the logits back to the input size (bilinear)."""
    h, w = image.shape[-2:]
    small = torch.nn.functional.interpolate(
        image[None], size=(round(h * scale), round(w * scale)), mode="bilinear",
        align_corners=False, antialias=True,
    )  # fmt: skip
    logits = model(small)
    return torch.nn.functional.interpolate(logits, size=(h, w), mode="bilinear")[0]


@pytest.mark.parametrize("scale", [0.5, 0.7, 1.6])
def test_scale_resizes_logits_back_bilinearly(scale):
    """Non-constant logits (a pointwise model on a random image, so windows equal the whole
    image's forward): nearest-neighbour resizing back would be off by the logits' gradients."""
    torch.manual_seed(1)
    weight = torch.randn(4, 3)
    image = _normalised_noise(3, 40, 60)
    config = WindowConfig(size=(14, 14), stride=(9, 9), scale=scale, batch_size=5)
    out = sliding_window_logits(_pointwise(weight), image, config)
    expected = _reference_at_scale(_pointwise(weight), image, scale)
    assert out.shape == (4, 40, 60)
    np.testing.assert_allclose(out, expected, atol=1e-5)
    # The check has teeth: these logits vary enough for nearest to be far off.
    nearest = torch.nn.functional.interpolate(
        _pointwise(weight)(
            torch.nn.functional.interpolate(image[None], scale_factor=scale, mode="bilinear")
        ),
        size=(40, 60),
        mode="nearest",
    )[0]
    assert (nearest - expected).abs().max() > 0.1


def _tiny_segmenter(num_classes=5):
    from claravid import models

    torch.manual_seed(0)
    return models.build_model("dinov2_vits14", num_classes=num_classes, **MODEL).eval()


def _smooth_image(h, w, seed=0):
    """A normalised image of smooth blobs (a real-looking input, not white noise)."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.randn(1, 3, h // 8 + 1, w // 8 + 1, generator=g) * 1.5
    smooth = torch.nn.functional.interpolate(coarse, size=(h, w), mode="bicubic")[0]
    return smooth.clamp(-1.8, 2.2)


def test_bf16_windows_agree_with_float32_on_the_cpu():
    model = _tiny_segmenter()
    image = _smooth_image(42, 56)
    with torch.no_grad():  # the float32 reference: the model's own forward, no windows
        ref = model(image[None])[0]
    assert WindowConfig().precision == "auto"
    auto = sliding_window_logits(model, image, WindowConfig(size=(42, 56)))
    np.testing.assert_allclose(auto, ref, atol=1e-5)  # auto is float32 on a CPU
    low = sliding_window_logits(model, image, WindowConfig(size=(42, 56), precision="bf16"))
    assert low.dtype == torch.float32 and not torch.equal(low, ref)  # autocast did run
    agreement = (low.argmax(0) == ref.argmax(0)).float().mean().item()
    assert agreement >= 0.97, agreement


def test_precision_settings():
    assert WindowConfig((14, 14)).precision == "auto"
    for bad in ("fp8", True):  # a boolean (amp on/off) names no precision
        with pytest.raises(ValueError, match="precision must be one of auto, fp32, bf16, fp16"):
            WindowConfig(precision=bad)
    assert flag_precision(None) == "auto" and flag_precision("fp16") == "fp16"
    with pytest.raises(ValueError, match="must be one of auto, fp32, bf16, fp16, got 'half'"):
        flag_precision("half")
    for value in ("bf16", "fp32"):  # ONNX runs at its exported precision
        with pytest.raises(ValueError, match="does nothing with --onnx"):
            flag_precision(value, pytorch=False)
    assert flag_precision(None, pytorch=False) == "auto"


def test_onnx_windows_equal_pytorch_windows(model_files, model_onnx):
    """The fast ONNX-vs-PyTorch numeric check of the default run (the export tests are slow):
    the session fixture's dynamic export, through the same windows as its checkpoint."""
    from claravid.models import OnnxSegmenter, load_checkpoint

    model = load_checkpoint(model_files["checkpoint"]).eval()
    runner = OnnxSegmenter(model_onnx["onnx"])
    image = _smooth_image(48, 64, seed=3)
    config = WindowConfig(size=(28, 42), stride=(14, 14))
    torch_logits = sliding_window_logits(model, image, config)
    onnx_logits = sliding_window_logits(runner, image, config)
    assert torch_logits.std() > 0
    np.testing.assert_allclose(onnx_logits, torch_logits, atol=1e-4)
