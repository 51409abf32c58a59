"""What each head takes, stated once (`claravid.models.heads.specs`) and checked by every entry
point before any work: the smallest input (UperNet: 2 x 2 patches), positive widths, and a
training batch its BatchNorm can normalise."""

import json

import cv2
import numpy as np
import onnx
import pytest
import torch

from claravid.eval.cli.evaluate import main as eval_main
from claravid.eval.cli.export import main as export_main
from claravid.eval.cli.predict import main as predict_main
from claravid.models import build_model, save_checkpoint
from claravid.models.export.metadata import KEY, PREFIX
from claravid.models.heads.specs import check_input_size, check_norm_batch
from tests.tiny import VIT

UPERNET = {"head": "upernet", "layers": [0, 1, 2, 3], "features": 8, "backbone_kwargs": VIT}
#: The one line every entry point prints for a one-patch-high window of a UperNet model.
TOO_SMALL = (
    "the upernet head needs {what} of at least 2 x 2 patches (28x28 px at patch size 14; its "
    "coarsest level halves the patch grid), got 252x14 (WxH)"
)


def test_the_smallest_input_of_each_head():
    for head in ("dpt", "linear"):
        check_input_size(head, 14, 14, 14)  # one patch: enough
    check_input_size("upernet", 28, 42, 14)
    with pytest.raises(ValueError) as err:
        check_input_size("upernet", 14, 252, 14, "a window")
    assert str(err.value) == (
        TOO_SMALL.format(what="a window") + ": use a window of at least 28 px a side"
    )


@pytest.fixture(scope="module")
def upernet_files(tmp_path_factory, model_onnx):
    """A tiny UperNet segmenter's checkpoint, an ONNX file whose metadata names the UperNet
    head, and a folder with one image."""
    folder = tmp_path_factory.mktemp("upernet")
    torch.manual_seed(0)
    model = build_model("dinov2_vits14", 8, **UPERNET).eval()
    checkpoint = save_checkpoint(model, folder / "model.pt")
    # A dynamic UperNet export takes minutes on a busy machine; the refusal reads the head from
    # the file's metadata before ONNX Runtime runs, so the session's dynamic DPT graph, its
    # metadata saying upernet, stands in (ONNX Runtime would run this graph at 252x14).
    proto = onnx.load(str(model_onnx["onnx"]))
    for prop in proto.metadata_props:
        if prop.key in (KEY, PREFIX + "model_args"):
            document = json.loads(prop.value)
            args = document.get("model_args", document)
            args.update(head="upernet", features=8)
            args.pop("out_channels", None)
            prop.value = json.dumps(document)
    onnx_file = folder / "model.onnx"
    onnx.save(proto, str(onnx_file))
    images = folder / "images"
    images.mkdir()
    cv2.imwrite(str(images / "a.png"), np.full((48, 64, 3), 90, np.uint8))
    return {"checkpoint": checkpoint, "onnx": onnx_file, "images": images}


def _one_line(capsys, code):
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


@pytest.mark.parametrize("flag", ["--checkpoint", "--onnx"])
def test_a_one_patch_window_is_refused_by_eval_and_predict(upernet_files, tmp_path, capsys, flag):
    # Before: the ONNX file failed inside ONNX Runtime ("MatMul dimension mismatch", a traceback).
    model = str(upernet_files[flag.removeprefix("--")])
    out = tmp_path / "predicted"
    code = predict_main([flag, model, str(upernet_files["images"]), "--window", "252x14",
                         "--palette", "uavid", "--output", str(out), "--no-progress"])  # fmt: skip
    assert TOO_SMALL.format(what="a window") in _one_line(capsys, code)
    assert not out.exists()
    report = tmp_path / "report"
    code = eval_main([flag, model, "--data", str(upernet_files["images"]), "--window", "252x14",
                      "--palette", "uavid", "--output", str(report), "--no-progress"])  # fmt: skip
    assert TOO_SMALL.format(what="a window") in _one_line(capsys, code)
    assert not report.exists()


def test_an_export_smaller_than_the_head_takes_is_refused_in_one_line(
    upernet_files, tmp_path, capsys
):
    # Before: 379 lines and 4 tracebacks ("Output size is too small"), exit 1.
    out = tmp_path / "small.onnx"
    code = export_main(["--checkpoint", str(upernet_files["checkpoint"]), "--output", str(out),
                        "--size", "252x14"])  # fmt: skip
    assert TOO_SMALL.format(what="an export size") in _one_line(capsys, code)
    assert not out.exists()


@pytest.mark.parametrize(
    ("head", "settings"),
    [("dpt", {"features": 0}), ("dpt", {"out_channels": [8, 0, 8, 8]}),
     ("upernet", {"features": 0}), ("dpt", {"features": -3})],
)  # fmt: skip
def test_a_head_width_under_one_is_refused_when_built(head, settings):
    # Before: DPT with features=0 was built, then failed at its first forward pass.
    key, value = next(iter(settings.items()))
    with pytest.raises(ValueError) as err:
        build_model("dinov2_vits14", 3, head=head, layers=[0, 1, 2, 3], backbone_kwargs=VIT,
                    **settings)  # fmt: skip
    assert str(err.value).startswith(f"{key} must be positive integer" if key == "out_channels"
                                     else f"{key} must be a positive integer")  # fmt: skip
    assert f"got {value!r}" in str(err.value)


def test_batch_norm_on_one_value_is_refused_up_front_in_training_only():
    torch.manual_seed(0)
    upernet = build_model("dinov2_vits14", 3, **UPERNET).train()
    with pytest.raises(ValueError) as err:  # before: PyTorch's "Expected more than 1 value"
        upernet(torch.randn(1, 3, 56, 56))
    assert str(err.value).startswith(
        "the upernet head trains BatchNorm, which needs more than one value per channel, and "
        "sees one value per image: 1 image(s) of 4 x 4 patches give 1; "
    )
    assert "drop_last=True" in str(err.value)
    assert upernet(torch.randn(2, 3, 28, 28)).shape == (2, 3, 28, 28)
    assert upernet.eval()(torch.randn(1, 3, 56, 56)).shape == (1, 3, 56, 56)  # predicting: fine
    linear = build_model("dinov2_vits14", 3, head="linear", backbone_kwargs=VIT).train()
    with pytest.raises(ValueError, match=r"one value per image and patch: 1 image\(s\) of 1 x 1"):
        linear(torch.randn(1, 3, 14, 14))
    assert linear(torch.randn(1, 3, 14, 28)).shape == (1, 3, 14, 28)  # two patches: two values
    check_norm_batch("dpt", 1, 1, 1, "")  # no BatchNorm
