"""Window and export sizes against the model's patch, on every entry point (issue 26): a size off
the patch grid is one line naming the two nearest valid sizes, before any image is read; a
model file that records no window runs at the model's natural size (640 for DINOv3's patches of
16, 630 for DINOv2's 14), not a hard 630."""

import json

import pytest
import torch

from claravid import models
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.eval import DataChoice, InferenceSettings, evaluate
from claravid.eval.cli.evaluate import main as eval_main
from claravid.eval.cli.export import main as export_main
from claravid.eval.cli.predict import main as predict_main
from claravid.eval.inference.run_model import evaluate_model
from claravid.eval.inference.windows import WindowConfig
from claravid.infra.cli import UsageError
from tests.tiny import MODEL as TINY

FRAME = "001_rural_1/45deg_low_h/000000"
# 630 with patches of 16: 39 x 16 = 624 or 40 x 16 = 640, said width x height.
FIX_630 = "not a multiple of the model's patch size 16: use 624x624 or 640x640"


@pytest.fixture(scope="module")
def plain_v3(tmp_path_factory):
    """A tiny DINOv3 SAT segmenter saved without a training config: it records no window and
    no statistics."""
    torch.manual_seed(0)
    model = models.build_model("dinov3_vitl16_sat", 8, **TINY).eval()
    return models.save_checkpoint(model, tmp_path_factory.mktemp("v3") / "plain.pt")


@pytest.fixture
def split(tmp_path):
    path = tmp_path / "one.txt"
    path.write_text(FRAME + "\n")
    return path


def _one_line(capsys, prog, message):
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith(f"{prog}: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert message in lines[0], lines[0]


def test_eval_and_predict_refuse_a_window_off_the_grid_in_one_line(
    plain_v3, claravid_root, split, tmp_path, capsys
):
    data = ["--data", str(claravid_root), "--palette", "uavid", "--split", str(split)]
    out = tmp_path / "rep"
    assert eval_main(["--checkpoint", str(plain_v3), *data, "--window", "630", "-o", str(out)]) == 2
    _one_line(capsys, "claravid-eval", f"window 630x630 (WxH) is {FIX_630} (--window)")
    assert not out.exists()  # nothing written, no image read
    image = str(claravid_root / "001_rural_1" / "left_rgb" / "45deg_low_h" / "000000.jpg")
    pred = tmp_path / "pred"
    assert predict_main(["--checkpoint", str(plain_v3), image, "--palette", "uavid",
                         "--window", "56x40", "-o", str(pred)]) == 2  # fmt: skip
    # 56 x 40: 48 or 64 wide, 32 or 48 high.
    _one_line(capsys, "claravid-predict", "patch size 16: use 48x32 or 64x48")


def test_the_python_api_refuses_it_with_the_same_message(plain_v3, claravid_root, split, tmp_path):
    data = DataChoice(root=claravid_root, palette="uavid", split=str(split))
    with pytest.raises(UsageError, match=FIX_630):
        evaluate(tmp_path / "rep", checkpoint=plain_v3, data=data,
                 inference=InferenceSettings(window=630))  # fmt: skip
    model = models.load_checkpoint(plain_v3).eval()
    dataset = ClaraVidSegmentation(claravid_root, split=split, palette="uavid")
    with pytest.raises(ValueError, match=FIX_630):
        evaluate_model(model, dataset, 8, WindowConfig(size=630))


def test_no_recorded_window_or_statistics_mean_the_model_s_own(
    plain_v3, claravid_root, split, tmp_path, capsys
):
    data = ["--data", str(claravid_root), "--palette", "uavid", "--split", str(split)]
    argv = ["--checkpoint", str(plain_v3), *data, "--bins", "1", "--hardest", "0",
            "--bootstrap", "0", "--no-progress", "-o", str(tmp_path / "rep")]  # fmt: skip
    assert eval_main(argv) == 0
    settings = json.loads((tmp_path / "rep" / "report.json").read_text())["source"]["settings"]
    assert settings["window"] == [640, 640] and settings["from"]["window"] == "default"
    assert settings["stride"] == [426, 426]  # two thirds of 640
    # Nor statistics: the model's own, SAT-493M's (the published numbers), not ImageNet's.
    sat = {"mean": [0.430, 0.411, 0.296], "std": [0.213, 0.156, 0.143]}
    assert settings["normalisation"] == sat and settings["from"]["normalisation"] == "default"
    image = str(claravid_root / "001_rural_1" / "left_rgb" / "45deg_low_h" / "000000.jpg")
    pred = tmp_path / "pred"
    assert predict_main(["--checkpoint", str(plain_v3), image, "--palette", "uavid",
                         "-o", str(pred), "--no-progress"]) == 0  # fmt: skip
    marker = json.loads((pred / "predictions.json").read_text())
    assert marker["source"]["settings"]["window"] == [640, 640]


def test_export_sizes_default_to_the_natural_size_and_name_the_two_nearest(
    plain_v3, tmp_path, capsys
):
    out = str(tmp_path / "m.onnx")
    assert export_main(["--checkpoint", str(plain_v3), "-o", out, "--size", "640x30"]) == 2
    _one_line(capsys, "claravid-export", "input size 640x30 (WxH) is not a multiple of the "
              "model's patch size 16: use --size 640x16 or --size 640x32")  # fmt: skip
    assert export_main(["--checkpoint", str(plain_v3), "-o", out, "--size", "630"]) == 2
    _one_line(capsys, "claravid-export", "use --size 624x624 or --size 640x640")
    assert not (tmp_path / "m.onnx").exists()
