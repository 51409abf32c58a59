"""The patch grid in ONNX graphs: the patch size of a file exported elsewhere, read from its
graph, and a ``--dynamic`` export that fails on sizes off the grid in ONNX Runtime itself."""

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from onnx import TensorProto, helper

from claravid.eval.inference.sources import load_source, resolve_settings
from claravid.infra.cli import UsageError
from claravid.models import ExportSettings, OnnxSegmenter, build_model, export_onnx
from claravid.models.export.graph_grid import guard_name, guard_patch_grid, patch_size_from_graph
from tests.tiny import WIDE_HEAD as HEAD

TINY_V3 = {"embed_dim": 32, "depth": 4, "num_heads": 2}


def _conv_graph(kernel, stride, *, attribute=True, cast=False, weight_kernel=None):
    """image [N,3,H,W] (H, W dynamic) -> (Cast ->) Conv -> out."""
    k = weight_kernel or kernel
    weight = helper.make_tensor(
        "w", TensorProto.FLOAT, [2, 3, k, k], np.ones(2 * 3 * k * k, np.float32).tolist()
    )
    attrs = {"strides": [stride, stride]}
    if attribute:
        attrs["kernel_shape"] = [kernel, kernel]
    nodes = []
    source = "image"
    if cast:
        nodes.append(helper.make_node("Cast", ["image"], ["half"], to=TensorProto.FLOAT16))
        nodes.append(helper.make_node("Cast", ["half"], ["back"], to=TensorProto.FLOAT))
        source = "back"
    nodes.append(helper.make_node("Conv", [source, "w"], ["out"], **attrs))
    graph = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["n", 3, "h", "w"])],
        [helper.make_tensor_value_info("out", TensorProto.FLOAT, ["n", 2, "gh", "gw"])],
        [weight],
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 23)])


@pytest.mark.parametrize(
    ("model", "patch"),
    [
        (_conv_graph(16, 16), 16),  # DINOv3's patch embedding
        (_conv_graph(14, 14, attribute=False), 14),  # kernel from the weights' shape
        (_conv_graph(16, 16, cast=True), 16),  # behind a float16 file's casts
        (_conv_graph(3, 1), None),  # an ordinary convolution: no patch grid
        (_conv_graph(16, 8), None),  # overlapping: not a patch embedding
    ],
)
def test_the_patch_size_is_read_from_the_graph(model, patch):
    assert patch_size_from_graph(model.graph) == patch


def _run(path, shape, x=None):
    """ONNX Runtime itself (not the toolkit's runner, which checks sizes before)."""
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    if x is None:
        x = np.random.default_rng(0).standard_normal(shape).astype(np.float32)
    return session.run(None, {"image": x})[0]


def test_the_grid_guard_refuses_sizes_off_the_grid_in_onnx_runtime(tmp_path):
    path = tmp_path / "conv.onnx"
    onnx.save(_conv_graph(4, 4), str(path))
    before = {shape: _run(path, shape) for shape in [(2, 3, 8, 12), (1, 3, 4, 4)]}
    assert _run(path, (1, 3, 10, 9)).shape == (1, 2, 2, 2)  # off the grid: silently floored
    guard_patch_grid(path, 4)
    onnx.checker.check_model(str(path))
    for shape, expected in before.items():  # on the grid: the same numbers
        np.testing.assert_array_equal(_run(path, shape), expected)
    for shape in [(1, 3, 10, 8), (1, 3, 8, 9), (1, 3, 2, 8), (2, 3, 3, 3)]:
        with pytest.raises(Exception, match=guard_name(4)):
            _run(path, shape)
    assert guard_name(4) == "image_height_and_width_must_be_multiples_of_4"


@pytest.fixture(scope="module")
def dynamic_v3(tmp_path_factory):
    """A tiny DINOv3 (patch 16) exported with dynamic H/W, and the same graph without the
    toolkit's metadata (as a plain ``torch.onnx.export`` leaves it)."""
    folder = tmp_path_factory.mktemp("grid")
    torch.manual_seed(0)
    model = build_model("dinov3_vits16", num_classes=3, backbone_kwargs=TINY_V3, **HEAD).eval()
    model.set_statistics([0.5, 0.4, 0.3], [0.2, 0.25, 0.3])  # e.g. a checkpoint's
    path = folder / "dynamic.onnx"
    export_onnx(model, path, ExportSettings(height=32, width=48, dynamic=True))
    # Without a training config the file records the model's statistics, not the backbone's.
    assert OnnxSegmenter(path).normalisation["std"] == [0.2, 0.25, 0.3]
    proto = onnx.load(str(path))
    del proto.metadata_props[:]
    foreign = folder / "foreign.onnx"
    onnx.save(proto, str(foreign))
    return model, path, foreign


@pytest.mark.slow
def test_a_dynamic_export_fails_off_the_grid_in_onnx_runtime(dynamic_v3):
    model, path, _ = dynamic_v3
    x = np.random.default_rng(1).standard_normal((1, 3, 48, 64)).astype(np.float32)
    with torch.no_grad():
        expected = model(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(_run(path, x.shape, x), expected, atol=1e-4)
    # Off the grid ONNX Runtime ran the model on the rows and columns the patches cover and
    # returned logits up to 0.057 off the model's; it now stops, naming what is wrong.
    for shape in [(1, 3, 40, 50), (1, 3, 48, 50), (1, 3, 8, 32)]:
        with pytest.raises(Exception, match="image_height_and_width_must_be_multiples_of_16"):
            _run(path, shape)


@pytest.mark.slow
def test_a_file_without_metadata_has_the_patch_of_its_graph(dynamic_v3):
    _, _, foreign = dynamic_v3
    runner = OnnxSegmenter(foreign)
    assert runner.metadata is None and runner.patch_size == 16  # was taken for 14
    with pytest.raises(ValueError, match=r"multiple of the patch size 16"):
        runner(np.zeros((1, 3, 42, 42), np.float32))
    source = load_source(onnx=foreign)
    # 64 = 4 patches of 16 is valid (it was refused, as no multiple of 14); 630 is not.
    settings = resolve_settings(source, window=64, palette="uavid", statistics="sat493m")
    assert settings.window.size == (64, 64)
    assert settings.window.mean == (0.430, 0.411, 0.296)  # named, not ImageNet's by default
    with pytest.raises(UsageError, match=r"patch size 16: use 624x624 or 640x640"):
        resolve_settings(source, window=630, palette="uavid", statistics="sat493m")
    with pytest.raises(UsageError, match=r"no claravid metadata.*pass --window to say"):
        resolve_settings(source, palette="uavid", statistics="imagenet")  # nor a window
    with pytest.raises(UsageError, match=r"unknown --statistics 'imagenet1k'"):
        resolve_settings(source, window=64, palette="uavid", statistics="imagenet1k")
