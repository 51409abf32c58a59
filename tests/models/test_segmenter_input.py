"""What a segmenter makes of the batches users bring: dtypes, value ranges, layouts, and the
statistics a checkpoint recorded."""

import warnings

import pytest
import torch

from claravid.models import InputRangeWarning, build_model, load_checkpoint, save_checkpoint
from tests.tiny import VIT_56 as TINY
from tests.tiny import WIDE_HEAD as HEAD

IMAGENET_MEAN = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
IMAGENET_STD = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)


def _model():
    torch.manual_seed(0)
    return build_model("dinov2_vits14", num_classes=5, backbone_kwargs=TINY, **HEAD).eval()


def _pixels(h=28, w=42, seed=1):
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (2, 3, h, w), dtype=torch.uint8, generator=g)


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16])
def test_a_model_cast_to_half_precision_takes_uint8_pixels(dtype):
    model = _model()
    pixels = _pixels()
    with torch.no_grad():
        reference = model(pixels)
        low = model.to(dtype)(pixels)  # crashed: "Input type (float) and bias type (...)"
        assert model.normalise(pixels).dtype == dtype
    assert low.dtype == dtype
    # Half precision keeps ~3 significant digits: compare relative to the logits' spread.
    assert (low.float() - reference).abs().max() < 0.1 * reference.std()


@pytest.mark.parametrize("dtype", [torch.float16, torch.float64])
def test_a_float_batch_of_another_dtype_is_cast_to_the_model_s(dtype):
    model = _model()
    x = (_pixels().float() / 255 - IMAGENET_MEAN) / IMAGENET_STD
    with torch.no_grad():
        expected = model(x.to(dtype).float())  # the same rounded values, in float32
        got = model(x.to(dtype))  # was PyTorch's raw conv error
    assert got.dtype == torch.float32
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=0)


def test_a_float_batch_of_0_255_pixels_is_refused():
    model = _model()
    with pytest.raises(ValueError, match=r"values in \[0, 255\].*0\.\.255 pixels\? pass them as "
                       r"uint8") as info:  # fmt: skip
        model(torch.full((1, 3, 28, 28), 255.0).index_fill_(3, torch.tensor([0]), 0.0))
    assert "within ±2.6 with mean (0.485, 0.456, 0.406)" in str(info.value)
    assert "\n" not in str(info.value)


def test_a_raw_0_1_batch_warns_once_saying_how_to_silence_it():
    model = _model()
    raw = _pixels().float() / 255  # torchgeo's float images in [0, 1]
    with pytest.warns(InputRangeWarning, match=r"no negative value.*raw pixels in \[0, 1\]") as rec:
        model(raw)
    message = str(rec[0].message)
    assert "filterwarnings('ignore', category=claravid.models.InputRangeWarning)" in message
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per model: a second batch says nothing
        model(raw)
        # Normalised batches hold negative values: no warning from another model either.
        _model()((raw - IMAGENET_MEAN) / IMAGENET_STD)
    with warnings.catch_warnings():  # what the message says silences it
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", category=InputRangeWarning)
        _model()(raw)


def test_normalise_names_a_channels_last_batch():
    model = _model()
    with pytest.raises(ValueError, match=r"shape \[2, 28, 42, 3\]: channels last\? x.permute"):
        model.normalise(_pixels().permute(0, 2, 3, 1))
    with pytest.raises(TypeError, match=r"uint8 pixels \[B,3,H,W\], got torch.float32"):
        model.normalise(_pixels().float())
    by_hand = (_pixels().float() / 255 - IMAGENET_MEAN) / IMAGENET_STD
    torch.testing.assert_close(model.normalise(_pixels()), by_hand)


def test_a_checkpoint_normalises_uint8_with_the_statistics_it_trained_with(tmp_path):
    model = _model()
    mean, std = [0.5, 0.4, 0.3], [0.2, 0.25, 0.3]  # not ImageNet's: the config named them
    config = {"data": {"augment": {"mean": mean, "std": std}}}
    save_checkpoint(model, tmp_path / "best.pt", config=config)
    loaded = load_checkpoint(tmp_path / "best.pt").eval()
    assert loaded.mean == tuple(mean) and loaded.std == tuple(std)
    pixels = _pixels()
    recorded = (pixels.float() / 255 - torch.tensor(mean).view(1, 3, 1, 1)) / torch.tensor(
        std
    ).view(1, 3, 1, 1)
    with torch.no_grad():
        torch.testing.assert_close(loaded(pixels), model(recorded), atol=1e-5, rtol=0)
        assert (loaded(pixels) - model(pixels)).abs().max() > 1e-3  # ImageNet's differ
    # Saved again without the config, the model keeps them; unset, the backbone's are back.
    save_checkpoint(loaded, tmp_path / "again.pt")
    assert load_checkpoint(tmp_path / "again.pt").std == tuple(std)
    loaded.set_statistics(None, None)
    assert loaded.mean == (0.485, 0.456, 0.406)
    save_checkpoint(loaded, tmp_path / "plain.pt")
    assert "statistics" not in torch.load(tmp_path / "plain.pt", weights_only=True)


@pytest.mark.parametrize(
    ("mean", "std", "match"),
    [
        ([123.7, 116.3, 103.5], [58.4, 57.1, 57.4], "divide 0–255 statistics by 255"),
        ([0.5, 0.5, 0.5], [0.2, 0.0, 0.2], r"std in \(0, 1\]"),
        ([0.5, float("nan"), 0.5], [0.2, 0.2, 0.2], "finite"),
        ([-0.1, 0.5, 0.5], [0.2, 0.2, 0.2], r"mean in \[0, 1\]"),
        ([0.5, 0.5], [0.2, 0.2, 0.2], r"mean needs 3 values"),
        ([0.5, 0.5, 0.5], None, "together"),
    ],
)
def test_unusable_statistics_are_refused(mean, std, match):
    with pytest.raises(ValueError, match=match):
        _model().set_statistics(mean, std)
