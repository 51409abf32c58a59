"""ONNX export, onnxruntime on other shapes than the export example, and the CLI."""

import numpy as np
import pytest
import torch

from models import ExportCheckError, OnnxSegmenter, build_model, export_onnx, save_checkpoint
from models.export import check_export, main

TINY = {"embed_dim": 32, "depth": 4, "num_heads": 2, "img_size": 56}
HEAD = {"layers": [0, 1, 2, 3], "features": 16, "out_channels": [8, 16, 32, 32]}


def _model(name):
    torch.manual_seed(0)
    return build_model(name, num_classes=3, backbone_kwargs=TINY, **HEAD).eval()


def _torch_logits(model, x):
    with torch.no_grad():
        return model(torch.from_numpy(x)).numpy()


@pytest.mark.slow
def test_fixed_size_export(tmp_path, capsys):
    model = _model("dinov2_vits14_reg")  # antialiased bicubic: stored positional table
    result = export_onnx(model, tmp_path / "m.onnx", height=42, width=70)
    assert result["check_shape"] == (3, 3, 42, 70) and result["max_abs_diff"] < 1e-4
    assert "max abs diff of logits" in capsys.readouterr().out
    assert model.backbone._frozen_pos is None  # export leaves the model as it was
    runner = OnnxSegmenter(tmp_path / "m.onnx")
    assert runner.input_size == (42, 70) and runner.num_classes == 3 and runner.patch_size == 14
    assert runner.model_args["backbone"] == "dinov2_vits14_reg"
    x = np.random.default_rng(0).standard_normal((1, 3, 42, 70)).astype(np.float32)
    np.testing.assert_allclose(runner(x), _torch_logits(model, x), atol=1e-4)
    with pytest.raises(ValueError, match=r"exported for 42x70 inputs, got 56x70.*--dynamic"):
        runner(np.zeros((1, 3, 56, 70), np.float32))
    with torch.no_grad():  # a changed model no longer matches the file
        model.head.head[-1].bias += 1.0
    with pytest.raises(ExportCheckError, match="differs from PyTorch by 1"):
        check_export(model, tmp_path / "m.onnx", 42, 70, dynamic=False)


@pytest.mark.slow
def test_dynamic_export_other_sizes(tmp_path):
    # Example at the native 4x4 grid: the offset bicubic must still follow other sizes.
    model = _model("dinov2_vits14")
    export_onnx(model, tmp_path / "d.onnx", height=56, width=56, dynamic=True)
    runner = OnnxSegmenter(tmp_path / "d.onnx")
    assert runner.input_size is None
    rng = np.random.default_rng(1)
    for shape in [(1, 3, 56, 56), (4, 3, 84, 42), (1, 3, 14, 98)]:
        x = rng.standard_normal(shape).astype(np.float32)
        np.testing.assert_allclose(runner(x), _torch_logits(model, x), atol=1e-4)
    with pytest.raises(ValueError, match="patch size 14: pad or resize it to 56x70"):
        runner(np.zeros((1, 3, 50, 60), np.float32))


@pytest.mark.slow
def test_cli(tmp_path, capsys):
    model = _model("dinov2_vits14")
    ckpt = save_checkpoint(model, tmp_path / "m.pt")
    out = tmp_path / "cli.onnx"
    assert main([str(ckpt), "--output", str(out), "--height", "28", "--width", "42"]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    x = np.random.default_rng(2).standard_normal((2, 3, 28, 42)).astype(np.float32)
    np.testing.assert_allclose(OnnxSegmenter(out)(x), _torch_logits(model, x), atol=1e-4)


def test_cli_errors(tmp_path, capsys):
    assert main([str(tmp_path / "none.pt"), "--output", str(tmp_path / "x.onnx")]) == 2
    assert "none.pt not found" in capsys.readouterr().err
    ckpt = save_checkpoint(_model("dinov2_vits14"), tmp_path / "m.pt")
    assert main([str(ckpt), "-o", str(tmp_path / "x.onnx"), "--height", "30"]) == 2
    assert "pad or resize it to 42x630" in capsys.readouterr().err
    with pytest.raises(FileNotFoundError, match="claravid-export"):
        OnnxSegmenter(tmp_path / "x.onnx")
