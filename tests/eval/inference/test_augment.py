"""Test-time augmentation against a reference written out from the published protocols' statement.

The reference below uses plain torch only (no code of the toolkit): each copy is resized
(bilinear, antialiased), mirrored when flipped, cut into windows by the official rule (rows
``max(H - hc + hs - 1, 0) // hs + 1``, window i from ``y1 = i*hs``, ``y2 = min(y1 + hc, H)``,
``y1 = max(y2 - hc, 0)``; with the DINOv3 rule a crop larger than the copy both ways becomes the
copy's small side, square), its window logits are summed and divided by the count, resized back
(bilinear, align_corners False) to the image's size, mirrored back, softmaxed, and the
probabilities are averaged over the copies.
"""

import gc
import math

import pytest
import torch
import torch.nn.functional as F

from claravid.eval.inference.augment import TTAConfig
from claravid.eval.inference.windows import (
    WindowConfig,
    class_probabilities,
    predict_labels,
    sliding_window_logits,
)

MEAN, STD = (0.4, 0.5, 0.6), (0.2, 0.25, 0.3)


def _tiny_conv(classes: int = 5) -> torch.nn.Module:
    """A random 3x3-conv model: zero padding at a window's border makes each window's logits
    depend on where the window lies, so the window rule matters."""
    torch.manual_seed(0)
    return torch.nn.Sequential(
        torch.nn.Conv2d(3, 6, 3, padding=1), torch.nn.Tanh(), torch.nn.Conv2d(6, classes, 1)
    ).eval()


# --- the reference, from the protocols' statement ------------------------------------------


def ref_dinov3_size(h, w, s, r):
    small = int(s * r)
    if r < 1:
        small = math.ceil(small / 32) * 32
    if h > w:
        return int(small * h / w + 0.5), small
    return small, int(small * w / h + 0.5)


def ref_mmseg_size(h, w, r):
    tw, th = int(w * r + 0.5), int(h * r + 0.5)
    f = min(max(tw, th) / max(h, w), min(tw, th) / min(h, w))
    return int(h * f + 0.5), int(w * f + 0.5)


def ref_slide(model, x, crop, stride, square_small):
    _, h, w = x.shape
    hc, wc = crop
    hs, ws = stride
    if square_small and hc > h and wc > w:
        hc = wc = min(h, w)
    rows = max(h - hc + hs - 1, 0) // hs + 1
    cols = max(w - wc + ws - 1, 0) // ws + 1
    preds, count = None, torch.zeros(1, h, w)
    for i in range(rows):
        for j in range(cols):
            y1, x1 = i * hs, j * ws
            y2, x2 = min(y1 + hc, h), min(x1 + wc, w)
            y1, x1 = max(y2 - hc, 0), max(x2 - wc, 0)
            with torch.no_grad():
                out = model(x[None, :, y1:y2, x1:x2])[0]
            if preds is None:
                preds = torch.zeros(out.shape[0], h, w)
            preds[:, y1:y2, x1:x2] += out
            count[:, y1:y2, x1:x2] += 1
    return preds / count


def reference(model, image_u8, crop, stride, ratios, flip, rule, s=None):
    x = (image_u8.float() / 255 - torch.tensor(MEAN)[:, None, None]) / torch.tensor(STD)[
        :, None, None
    ]
    h, w = x.shape[-2:]
    copies = [(r, False) for r in ratios] + ([(r, True) for r in ratios] if flip else [])
    total = 0
    for r, flipped in copies:
        size = ref_dinov3_size(h, w, s, r) if rule == "dinov3" else ref_mmseg_size(h, w, r)
        c = F.interpolate(x[None], size=size, mode="bilinear", align_corners=False,
                          antialias=True)[0]  # fmt: skip
        if flipped:
            c = torch.flip(c, dims=[2])
        logits = ref_slide(model, c, crop, stride, rule == "dinov3")
        logits = F.interpolate(logits[None], size=(h, w), mode="bilinear",
                               align_corners=False)[0]  # fmt: skip
        if flipped:
            logits = torch.flip(logits, dims=[2])
        total = total + torch.softmax(logits, dim=0)
    return total / len(copies)


# --- the toolkit against it -----------------------------------------------------------------

CASES = [
    # rule, crop, stride, ratios, S: a window that divides nothing; ratios below 1 (rounded up
    # to 32) and above; a crop larger than the small copies both ways (the square rule).
    ("dinov3", (24, 24), (16, 16), (0.5, 0.9, 1.0, 1.3), 40),
    ("dinov3", (64, 56), (42, 37), (0.5, 0.75, 1.0, 1.1), 40),
    ("mmseg", (24, 32), (16, 21), (0.5, 0.75, 1.0, 1.25), None),
    ("mmseg", (48, 48), (32, 32), (0.5, 1.0, 1.5), None),
]


@pytest.mark.parametrize(("rule", "crop", "stride", "ratios", "s"), CASES)
def test_tta_probabilities_equal_the_written_out_protocol(rule, crop, stride, ratios, s):
    model = _tiny_conv()
    torch.manual_seed(1)
    image = torch.randint(0, 256, (3, 45, 70), dtype=torch.uint8)  # non-square, odd
    tta = TTAConfig(ratios, flip=True, rule=rule, size=s)
    config = WindowConfig(size=crop, stride=stride, batch_size=3, mean=MEAN, std=STD, tta=tta)
    got = class_probabilities(model, image, config)
    want = reference(model, image, crop, stride, ratios, True, rule, s)
    assert got.shape == want.shape == (5, 45, 70)
    assert (got - want).abs().max() <= 1e-5
    assert torch.equal(predict_labels(model, image, config), got.argmax(0))


def test_a_tall_image_gets_its_small_side_from_the_width():
    model = _tiny_conv()
    image = torch.randint(
        0, 256, (3, 71, 44), dtype=torch.uint8, generator=torch.Generator().manual_seed(2)
    )
    tta = TTAConfig((0.8, 1.2), flip=False, rule="dinov3", size=36)
    config = WindowConfig(size=(32, 32), stride=(20, 20), mean=MEAN, std=STD, tta=tta)
    want = reference(model, image, (32, 32), (20, 20), (0.8, 1.2), False, "dinov3", 36)
    assert (class_probabilities(model, image, config) - want).abs().max() <= 1e-5


def test_copy_sizes_by_hand():
    # DINOv3: S 512, ratio 0.9 -> 460 -> up to 480; 1.05 -> 537; the other side of a 4:3 image.
    dinov3 = TTAConfig.preset("dinov3", size=512)
    assert dinov3.copy_size(600, 800, 0.9) == (480, 640)
    assert dinov3.copy_size(600, 800, 1.05) == (537, 716)  # int(537 * 4 / 3 + 0.5)
    assert dinov3.copy_size(800, 600, 1.0) == (683, 512)  # a tall image: the width is small
    # S left to the image: its short side at the window config's scale.
    assert TTAConfig((1.0,)).copy_size(600, 800, 1.0, scale=0.5) == (300, 400)
    # mmseg: 0.75 of 375 x 500 -> target (375, 281); factor min(375/500, 281/375).
    mmseg = TTAConfig.preset("mmseg")
    assert mmseg.copy_size(375, 500, 0.75) == (281, 375)
    assert [c for c in mmseg.copies()][:2] == [(0.5, False), (0.75, False)]
    assert len(mmseg.copies()) == 12


def test_one_copy_at_ratio_one_is_the_plain_evaluation():
    """No mirror, one ratio of 1 at the image's own size: the softmax of the window logits."""
    model = _tiny_conv()
    image = torch.randint(
        0, 256, (3, 45, 70), dtype=torch.uint8, generator=torch.Generator().manual_seed(3)
    )
    plain = WindowConfig(size=(24, 24), stride=(16, 16), mean=MEAN, std=STD)
    tta = WindowConfig(size=(24, 24), stride=(16, 16), mean=MEAN, std=STD, tta=TTAConfig())
    want = sliding_window_logits(model, image, plain).softmax(0)
    assert (class_probabilities(model, image, tta) - want).abs().max() <= 1e-6
    assert (class_probabilities(model, image, plain) - want).abs().max() == 0


class _PatchModel(torch.nn.Module):
    """A 1x1-conv model that, like the segmenter, takes patch multiples only."""

    patch_size = 8

    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(4)
        self.conv = torch.nn.Conv2d(3, 4, 1)

    def forward(self, x):
        assert x.shape[-2] % 8 == 0 and x.shape[-1] % 8 == 0, tuple(x.shape)
        return self.conv(x)


def test_windows_shrunk_to_a_small_copy_are_padded_to_the_patch_and_cut_back():
    """A copy smaller than the window gives windows that are no patch multiple: they are padded
    for the model and the padding's logits dropped (pointwise logits show any misplacement)."""
    model = _PatchModel()
    image = torch.randint(
        0, 256, (3, 45, 70), dtype=torch.uint8, generator=torch.Generator().manual_seed(5)
    )
    tta = TTAConfig((0.5, 1.0), flip=True, rule="mmseg")
    config = WindowConfig(size=(48, 48), stride=(32, 32), mean=MEAN, std=STD, tta=tta)
    got = class_probabilities(model, image, config)
    want = reference(model.conv, image, (48, 48), (32, 32), (0.5, 1.0), True, "mmseg")
    assert (got - want).abs().max() <= 1e-5


def test_memory_does_not_grow_with_the_copies():
    """While the model runs, the image-size [K,H,W] tensors alive are the running sum and at
    most the buffer of the copy in flight (a copy at ratio 1 is image-size), whether there are
    2 copies or 12: nothing is kept per copy."""
    h, w, k = 45, 70, 5
    conv = _tiny_conv(k)
    calls: list[int] = []

    def model(x):  # one call per copy (the batch holds every window); counts at the last
        calls.append(0)
        if len(calls) == last:
            gc.collect()
            found = [o for o in gc.get_objects() if type(o) is torch.Tensor]
            calls[-1] = sum(tuple(o.shape) == (k, h, w) for o in found)
        return conv(x)

    image = torch.randint(0, 256, (3, h, w), dtype=torch.uint8)
    peaks = []
    for scales in ((1.0,), (0.5, 0.75, 1.0, 1.25, 1.5, 1.75)):
        calls.clear()
        tta = TTAConfig(scales, flip=True, rule="mmseg")
        last = len(tta.copies())
        config = WindowConfig(size=(32, 32), stride=(21, 21), batch_size=64, mean=MEAN,
                              std=STD, tta=tta)  # fmt: skip
        class_probabilities(model, image, config)
        assert len(calls) == last
        peaks.append(calls[-1])
    assert peaks[0] == peaks[1] <= 2


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="unknown TTA rule"):
        TTAConfig(rule="timm")
    with pytest.raises(ValueError, match="TTA scales"):
        TTAConfig(())
    with pytest.raises(ValueError, match="TTA scales"):
        TTAConfig((1.0, -0.5))
    with pytest.raises(ValueError, match="dinov3 rule"):
        TTAConfig(rule="mmseg", size=512)
    with pytest.raises(ValueError, match="unknown TTA preset"):
        TTAConfig.preset("ade")
    with pytest.raises(ValueError, match="must be a TTAConfig"):
        WindowConfig(tta="dinov3")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="averages probabilities"):
        config = WindowConfig(size=(8, 8), mean=MEAN, std=STD, tta=TTAConfig())
        sliding_window_logits(_tiny_conv(), torch.zeros(3, 8, 8, dtype=torch.uint8), config)


def test_the_record_round_trips():
    tta = TTAConfig.preset("dinov3", size=896)
    assert TTAConfig.from_record(tta.describe()) == tta
    assert tta.describe() == {"rule": "dinov3", "scales": [0.9, 0.95, 1.0, 1.05, 1.1],
                              "flip": True, "size": 896}  # fmt: skip
