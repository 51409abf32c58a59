"""``--precision`` of ``claravid-eval`` and ``claravid-predict``: bf16 on a CPU, bad values."""

import json

import cv2
import numpy as np
import pytest
import torch

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.transforms import eval_transforms
from claravid.eval.cli.evaluate import main as eval_main
from claravid.eval.cli.predict import main as predict_main
from claravid.models import load_checkpoint

FRAMES = ["001_rural_1/45deg_low_h/000000", "003_urban_1/55deg_mid_h/000000"]


def _fp32_windows(model, image, wh, ww):
    """float32 logits of 42x56 windows at the corners of a 48x64 image, averaged: restated
    for this size (stride 2/3 of the window gives starts 0 and the flush one)."""
    h, w = image.shape[-2:]
    total, hits = torch.zeros(model.num_classes, h, w), torch.zeros(h, w)
    for y in (0, h - wh):
        for x in (0, w - ww):
            with torch.no_grad():
                total[:, y : y + wh, x : x + ww] += model(image[None, :, y : y + wh, x : x + ww])[0]
            hits[y : y + wh, x : x + ww] += 1
    return total / hits


def test_eval_in_bf16_agrees_with_float32(model_files, claravid_root, tmp_path):
    split = tmp_path / "frames.txt"
    split.write_text("\n".join(FRAMES) + "\n")
    preds = tmp_path / "preds"
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--split", str(split), "--window",
            "56x42", "--bins", "1", "--no-progress", "--precision", "bf16",
            "--save-predictions", str(preds), "--output", str(tmp_path / "rep")]  # fmt: skip
    assert eval_main(argv) == 0
    source = json.loads((tmp_path / "rep" / "report.json").read_text())["source"]
    assert source["precision"] == "bf16"
    model = load_checkpoint(model_files["checkpoint"]).eval()
    data = ClaraVidSegmentation(claravid_root, split=split, palette="uavid",
                                transforms=eval_transforms())  # fmt: skip
    for i, key in enumerate(FRAMES):
        image = data[i]["image"]
        assert image.shape[-2:] == (48, 64)
        expected = _fp32_windows(model, image, 42, 56).argmax(0).numpy()
        saved = cv2.imread(str(preds / f"{key}.png"), cv2.IMREAD_UNCHANGED)
        agreement = (saved == expected).mean()
        assert agreement >= 0.97, (key, agreement)


def test_eval_default_is_float32_on_the_cpu(model_files, tmp_path, capsys):
    split = tmp_path / "frames.txt"
    split.write_text(FRAMES[0] + "\n")
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--split", str(split), "--window",
            "56x42", "--bins", "1", "--no-progress"]  # fmt: skip
    assert eval_main([*argv, "--output", str(tmp_path / "a")]) == 0
    source = json.loads((tmp_path / "a" / "report.json").read_text())["source"]
    assert source["precision"] == "fp32"


@pytest.mark.parametrize("value", ["fp8", "BF16", "off"])
def test_bad_precision_is_one_line_exit_2(model_files, tmp_path, capsys, value):
    ckpt = ["--checkpoint", str(model_files["checkpoint"]), "--precision", value]
    message = f"argument --precision: invalid choice: '{value}' (choose from "
    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.zeros((28, 28, 3), np.uint8))
    for main, argv in ((eval_main, [*ckpt, "--output", str(tmp_path / "e")]),
                       (predict_main, [str(image), *ckpt, "-o", str(tmp_path / "p")])):  # fmt: skip
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and message in err, err
    assert not (tmp_path / "e").exists() and not (tmp_path / "p").exists()


def test_bf16_is_for_the_pytorch_model_only(model_files, model_onnx, tmp_path, capsys):
    onnx = ["--onnx", str(model_onnx["onnx"]), "--precision", "bf16"]
    assert eval_main([*onnx, "--output", str(tmp_path / "e")]) == 2
    message = "--precision does nothing with --onnx"  # any precision: it runs as exported
    assert message in capsys.readouterr().err
    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.zeros((28, 28, 3), np.uint8))
    assert predict_main([str(image), *onnx, "-o", str(tmp_path / "p")]) == 2
    assert message in capsys.readouterr().err
