"""Cheaper exports: float16 (LayerNorm/Softmax/final resize kept float32) and int8."""

import numpy as np
import onnx
import pytest
import torch

from claravid.eval.cli.export import main
from claravid.models import OnnxSegmenter, build_model
from claravid.models.export.fp16 import convert_to_fp16
from claravid.models.export.int8 import quantize_int8
from claravid.models.export.metadata import normalisation_from_config
from claravid.models.export.onnx import ExportSettings, check_export, export_onnx, smooth_images
from tests.tiny import VIT_56 as TINY
from tests.tiny import WIDE_HEAD as HEAD

SIZE = 28


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(0)
    model = build_model("dinov2_vits14", num_classes=4, backbone_kwargs=TINY, **HEAD).eval()
    path = tmp_path_factory.mktemp("precision") / "fp32.onnx"
    export_onnx(model, path, ExportSettings(height=SIZE, width=SIZE, check=False))
    x = smooth_images((2, 3, SIZE, SIZE), normalisation_from_config(None), seed=5)
    with torch.no_grad():
        expected = model(torch.from_numpy(x)).numpy()
    return model, path, x, expected


def _agreement(a, b):
    return float((a.argmax(1) == b.argmax(1)).mean())


def test_fp16_keeps_layernorm_and_the_final_resize_in_fp32(exported, tmp_path):
    _, path, x, expected = exported
    counts = convert_to_fp16(str(path), str(tmp_path / "h.onnx"))
    assert counts["fp16_nodes"] > 0
    proto = onnx.load(str(tmp_path / "h.onnx"))
    graph = proto.graph
    half, single = onnx.TensorProto.FLOAT16, onnx.TensorProto.FLOAT
    assert graph.input[0].type.tensor_type.elem_type == single
    assert graph.output[0].type.tensor_type.elem_type == single
    weights = [t for t in graph.initializer if t.data_type in (half, single) and t.dims]
    assert sum(t.data_type == half for t in weights) > len(weights) // 2
    producers = {o: n for n in graph.node for o in n.output}
    # Every LayerNorm and the last Resize read a value cast to float32 (or a float32 weight).
    kept = [n for n in graph.node if n.op_type == "LayerNormalization"]
    kept.append([n for n in graph.node if n.op_type == "Resize"][-1])
    for node in kept:
        src = producers[node.input[0]]
        assert src.op_type == "Cast" and src.attribute[0].i == single, node.name
    assert all(
        any(a.name == "softmax_precision" and a.i == single for a in n.attribute)
        for n in graph.node
        if n.op_type == "Attention"
    )
    got = OnnxSegmenter(tmp_path / "h.onnx", providers="cpu")(x)
    assert got.dtype == np.float32
    assert np.abs(got - expected).max() < 5e-3
    assert _agreement(got, expected) > 0.99


def test_int8_dynamic_and_static_load_run_and_agree(exported, tmp_path):
    model, path, x, expected = exported
    info = quantize_int8(path, tmp_path / "d.onnx")
    assert info["mode"] == "dynamic"
    ops = {n.op_type for n in onnx.load(str(tmp_path / "d.onnx")).graph.node}
    assert "QAttention" not in ops and ("MatMulInteger" in ops or "DynamicQuantizeMatMul" in ops)
    got = OnnxSegmenter(tmp_path / "d.onnx", providers="cpu")(x)  # it loads and runs
    assert _agreement(got, expected) >= 0.97
    batches = [smooth_images((1, 3, SIZE, SIZE), normalisation_from_config(None), seed=s)
               for s in range(4)]  # fmt: skip
    info = quantize_int8(path, tmp_path / "s.onnx", calibration=batches, per_channel=True)
    assert info["mode"] == "static"
    ops = {n.op_type for n in onnx.load(str(tmp_path / "s.onnx")).graph.node}
    assert "QuantizeLinear" in ops and "DequantizeLinear" in ops
    got = OnnxSegmenter(tmp_path / "s.onnx", providers="cpu")(x)
    assert _agreement(got, expected) >= 0.9
    result = check_export(model, tmp_path / "s.onnx", SIZE, SIZE, False, None, 0.5)
    assert 0.5 <= result["agreement"] <= 1 and result["max_abs_diff"] > 0


def test_refusal_below_min_agreement_leaves_no_file(tmp_path, capsys):
    from claravid.models import save_checkpoint

    torch.manual_seed(0)
    model = build_model("dinov2_vits14", num_classes=4, backbone_kwargs=TINY, **HEAD).eval()
    with torch.no_grad():  # weight outliers: per-tensor int8 rounds every other weight to ~0
        for block in model.backbone.blocks:
            for linear in (block.attn.qkv, block.mlp.fc1, block.mlp.fc2):
                linear.weight[0, 0] = 200 * linear.weight.abs().max()
        model.head.head[-1].bias.zero_()  # classes compete on features, not on their biases
    ckpt = save_checkpoint(model, tmp_path / "m.pt")
    out = tmp_path / "q.onnx"
    argv = ["--checkpoint", str(ckpt), "-o", str(out), "--size", str(SIZE),
            "--dtype", "int8", "--min-agreement", "1"]  # fmt: skip
    assert main(argv) == 1  # 99.96 % of pixels agree
    captured = capsys.readouterr()
    assert "agrees with PyTorch on 99.9" in captured.err
    assert "< --min-agreement 100 %" in captured.err and "nothing was written" in captured.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.pt"]


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--dtype", "bf16"], "invalid choice: 'bf16'"),
        (["--min-agreement", "1.5"], "expected a fraction in [0, 1], got '1.5'"),
        (["--min-agreement", "x"], "expected a fraction in [0, 1], got 'x'"),
        (["--calibration-images", "0"], "expected a positive integer, got '0'"),
    ],
)
def test_cli_rejects_bad_precision_flags(tmp_path, capsys, args, match):
    with pytest.raises(SystemExit) as info:
        main(["m.pt", "-o", str(tmp_path / "x.onnx"), *args])
    assert info.value.code == 2
    assert match in capsys.readouterr().err


def test_cli_rejects_calibration_misuse(tmp_path, capsys):
    (tmp_path / "m.pt").write_bytes(b"")
    for args, match in [
        (["--calibration", str(tmp_path)], "apply to --dtype int8 only"),
        (["--per-channel"], "apply to --dtype int8 only"),
        (["--dtype", "int8", "--calibration-images", "8"], "does nothing without --calibr"),
        (["--dtype", "int8", "--calibration", str(tmp_path / "no")], "is not a folder"),
    ]:
        ckpt = ["--checkpoint", str(tmp_path / "m.pt")]
        assert main([*ckpt, "-o", str(tmp_path / "x.onnx"), *args]) == 2
        err = capsys.readouterr().err
        lines = [x for x in err.splitlines() if x.startswith("claravid-export: error:")]
        assert len(lines) == 1 and match in lines[0] and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.pt"]


def test_cli_names_the_files_number_format_dtype_not_precision(tmp_path, capsys):
    """One meaning per flag: ``--precision`` is an autocast on every other command, and an
    export has none; the file's number format is ``--dtype``."""
    with pytest.raises(SystemExit) as info:
        main(["--checkpoint", "m.pt", "-o", str(tmp_path / "x.onnx"), "--precision", "int8"])
    assert info.value.code == 2
    assert "unrecognized arguments: --precision int8" in capsys.readouterr().err
