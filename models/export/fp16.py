"""Convert an exported float32 graph to float16, keeping the overflow-prone ops in float32.

fp16 ViTs overflow in LayerNorm (the variance of large activations passes 65504) and lose the
small differences Softmax needs; the final logit resize is cheap and decides the argmax. Those
ops stay float32 with Casts around them; the fused ``Attention`` op computes its softmax in
float32 (``softmax_precision``). The graph's input and output stay float32, so callers see no
difference.

Which values become float16 follows the data, not the dtype: a node is converted when one of
its float inputs derives from the image (an "activation"). Shape arithmetic done in float
(sizes for Resize, positional-table grids) never touches the image and stays float32, where
float16 would round sizes above 2048. Weights used only by converted nodes are stored in
float16 (half the file); others stay float32, cast where they meet float16 data.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

#: Ops kept in float32.
KEEP_FP32 = frozenset({"LayerNormalization", "Softmax", "LogSoftmax"})
#: Inputs that are float but must keep their own type (Resize's roi and scales).
FIXED_INPUTS = {"Resize": {1, 2}}


def convert_to_fp16(src: str, dst: str, keep_ops: frozenset[str] = KEEP_FP32) -> dict[str, int]:
    """Read the float32 ONNX file ``src``, write its float16 version to ``dst``.

    Args:
        src: The float32 export (self-contained, not external data).
        dst: Where to write the converted graph.
        keep_ops: Op types kept in float32 (besides the final Resize that makes the output).

    Returns:
        Counts: ``{"fp16_nodes", "fp32_nodes", "casts"}``.
    """
    import onnx

    model = onnx.shape_inference.infer_shapes(onnx.load(src))  # every value's element type
    graph = model.graph
    types = _element_types(graph)
    # Nodes are named by their index: protobuf's Python wrappers are not stable objects.
    nodes = list(graph.node)
    converted, half = _half_nodes(graph, nodes, types, keep_ops)
    consumers: dict[str, list[tuple[int, int]]] = {}
    for k, node in enumerate(nodes):
        for i, name in enumerate(node.input):
            consumers.setdefault(name, []).append((k, i))

    def wants_half(k: int, index: int) -> bool:
        return k in converted and index not in FIXED_INPUTS.get(nodes[k].op_type, set())

    half |= _store_half(graph, nodes, types, consumers, wants_half)
    casts = _insert_casts(graph, nodes, types, converted, half)
    onnx.checker.check_model(model)
    onnx.save(model, dst)
    return {
        "fp16_nodes": len(converted),
        "fp32_nodes": len(nodes) - len(converted),
        "casts": casts,
    }


def _element_types(graph: Any) -> dict[str, int]:
    """The element type of every typed value: inputs, outputs, inferred values, weights and
    constants."""
    types: dict[str, int] = {}
    for v in [*graph.input, *graph.output, *graph.value_info]:
        types[v.name] = v.type.tensor_type.elem_type
    for t in graph.initializer:
        types[t.name] = t.data_type
    for node in graph.node:
        if node.op_type == "Constant":
            for a in node.attribute:
                if a.name == "value":
                    types[node.output[0]] = a.t.data_type
    return types


def _half_nodes(
    graph: Any, nodes: list[Any], types: dict[str, int], keep_ops: frozenset[str]
) -> tuple[set[int], set[str]]:
    """(the nodes that compute in float16, the values they make): every node one of whose float
    inputs derives from the image, except the kept ops and the final resize."""
    from onnx import TensorProto

    FLOAT, HALF = TensorProto.FLOAT, TensorProto.FLOAT16
    # The final resize (the one that makes the graph output) also stays float32.
    outputs = {o.name for o in graph.output}
    keep_nodes = {k for k, n in enumerate(nodes) if n.op_type in keep_ops}
    keep_nodes |= {
        k for k, n in enumerate(nodes) if n.op_type == "Resize" and outputs & set(n.output)
    }
    active = {i.name for i in graph.input if types.get(i.name) == FLOAT}
    half: set[str] = set()  # values that are float16 after conversion
    converted: set[int] = set()  # nodes computing in float16
    for k, node in enumerate(nodes):
        fixed = FIXED_INPUTS.get(node.op_type, set())
        data_in = [n for i, n in enumerate(node.input) if n and i not in fixed]
        if not any(n in active for n in data_in):
            continue
        floats_out = [o for o in node.output if types.get(o) in (FLOAT, HALF)]
        active.update(floats_out)
        if node.op_type == "Cast" and not floats_out:
            continue  # activation -> int: reads whatever float type it gets
        if k in keep_nodes:
            continue
        converted.add(k)
        half.update(floats_out)
    return converted, half


def _store_half(
    graph: Any,
    nodes: list[Any],
    types: dict[str, int],
    consumers: dict[str, list[tuple[int, int]]],
    wants_half: Callable[[int, int], bool],
) -> set[str]:
    """Weights and constants read only where float16 is wanted, stored in float16 (in place):
    their names."""
    from onnx import TensorProto, numpy_helper

    FLOAT = TensorProto.FLOAT
    inits = {t.name: t for t in graph.initializer}
    half: set[str] = set()
    for name, uses in consumers.items():
        if types.get(name) != FLOAT or not uses or not all(wants_half(n, i) for n, i in uses):
            continue
        if name in inits:
            t = inits[name]
            t.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(t).astype("float16"), name))
            half.add(name)
    for node in nodes:
        if node.op_type != "Constant" or types.get(node.output[0]) != FLOAT:
            continue
        uses = consumers.get(node.output[0], [])
        if uses and all(wants_half(n, i) for n, i in uses):
            for a in node.attribute:
                if a.name == "value":
                    array = numpy_helper.to_array(a.t).astype("float16")
                    a.t.CopyFrom(numpy_helper.from_array(array, a.t.name))
            half.add(node.output[0])
    return half


def _insert_casts(
    graph: Any, nodes: list[Any], types: dict[str, int], converted: set[int], half: set[str]
) -> int:
    """Rewrite the graph (in place) with a Cast wherever float16 and float32 meet, the graph's
    outputs kept float32; the number of casts between nodes."""
    from onnx import TensorProto, helper

    FLOAT, HALF = TensorProto.FLOAT, TensorProto.FLOAT16
    casts: dict[tuple[str, int], str] = {}
    new_nodes: list[Any] = []

    def cast(name: str, to: int) -> str:
        key = (name, to)
        if key not in casts:
            casts[key] = f"{name}__to_{'fp16' if to == HALF else 'fp32'}"
            new_nodes.append(helper.make_node("Cast", [name], [casts[key]], to=to))
        return casts[key]

    rewritten: list[Any] = []
    for k, node in enumerate(nodes):
        fixed = FIXED_INPUTS.get(node.op_type, set())
        is_half = k in converted
        for i, name in enumerate(node.input):
            if not name or i in fixed or types.get(name) not in (FLOAT, HALF):
                continue
            if is_half and name not in half:
                node.input[i] = cast(name, HALF)
            elif not is_half and name in half:
                node.input[i] = cast(name, FLOAT)
        if is_half:
            for a in node.attribute:
                if node.op_type == "Cast" and a.name == "to" and a.i == FLOAT:
                    a.i = HALF
            if node.op_type == "Attention":
                node.attribute.append(helper.make_attribute("softmax_precision", FLOAT))
        rewritten.extend(new_nodes)
        new_nodes.clear()
        rewritten.append(node)
    del graph.node[:]
    graph.node.extend(rewritten)
    for out in graph.output:  # the graph's outputs stay float32
        if out.name in half:
            inner = out.name + "__fp16"
            for node in graph.node:
                node.output[:] = [inner if o == out.name else o for o in node.output]
                node.input[:] = [inner if i == out.name else i for i in node.input]
            graph.node.append(helper.make_node("Cast", [inner], [out.name], to=FLOAT))
    del graph.value_info[:]  # stale types; onnxruntime infers its own
    return len(casts)
