"""The patch grid inside an ONNX graph: read the patch size from it, and make sizes off it fail.

A file exported without the toolkit (a plain ``torch.onnx.export``) carries no metadata, so its
patch size is read from the graph itself: the patch embedding is the one convolution on the
image whose kernel equals its stride (14 for DINOv2, 16 for DINOv3).

A ``--dynamic`` export takes any height and width, but the model is defined on the patch grid
only: ONNX Runtime would run a size off it with the last rows and columns dropped by the patch
embedding, and logits that differ from what the model gives on the grid. `guard_patch_grid`
inserts a ``Reshape`` of the image to ``[B, 3, H // p * p, W // p * p]`` in front of the graph:
on the grid it changes nothing, off it ONNX Runtime stops with an error naming the node, whose
name says what is wrong (``image_height_and_width_must_be_multiples_of_16``).
"""

from __future__ import annotations

import os
from typing import Any

#: Nodes a patch embedding may sit behind on its way from the input (a float16 file's Cast, the
#: grid guard's Reshape).
_PASS_THROUGH = {"Cast", "Identity", "Reshape"}


def patch_size_from_graph(graph: Any) -> int | None:
    """The patch size of an ONNX graph (``onnx.GraphProto``): the kernel of the convolution on
    the image input whose kernel equals its stride; None when there is no such single one."""
    from onnx import helper

    consumers: dict[str, list[Any]] = {}
    for node in graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    shapes = {init.name: list(init.dims) for init in graph.initializer}
    initialised = set(shapes)
    inputs = [i.name for i in graph.input if i.name not in initialised]
    found: set[int] = set()
    frontier, seen = inputs[:1], set()
    while frontier:
        name = frontier.pop()
        if name in seen:
            continue
        seen.add(name)
        for node in consumers.get(name, []):
            if node.op_type in _PASS_THROUGH and node.input[0] == name:
                frontier.extend(node.output)
            elif node.op_type == "Conv" and node.input[0] == name:
                attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
                kernel = list(attrs.get("kernel_shape") or shapes.get(node.input[1], [])[2:])
                strides = list(attrs.get("strides") or [1] * len(kernel))
                if len(kernel) == 2 and kernel == strides and kernel[0] == kernel[1] > 1:
                    found.add(int(kernel[0]))
    return found.pop() if len(found) == 1 else None


def patch_size_from_file(path: str | os.PathLike) -> int | None:
    """`patch_size_from_graph` of an ONNX file (its weights stay on disk when external)."""
    import onnx

    return patch_size_from_graph(onnx.load(str(path), load_external_data=False).graph)


def guard_name(patch_size: int) -> str:
    """The name of the guard node: ONNX Runtime's error about it names it."""
    return f"image_height_and_width_must_be_multiples_of_{patch_size}"


def guard_patch_grid(path: str | os.PathLike, patch_size: int) -> None:
    """Make the ONNX file at ``path`` refuse images whose height or width is not a multiple of
    ``patch_size``, in the graph (see the module's docstring); in place.

    Raises:
        ValueError: the graph has not one image input.
    """
    import onnx
    from onnx import TensorProto, helper

    proto = onnx.load(str(path), load_external_data=False)
    graph = proto.graph
    initialised = {init.name for init in graph.initializer}
    inputs = [i.name for i in graph.input if i.name not in initialised]
    if len(inputs) != 1:
        raise ValueError(f"expected one image input in {path}, found {inputs}")
    image, p = inputs[0], int(patch_size)
    name = guard_name(p)
    guarded = f"{name}_image"
    for node in graph.node:  # every consumer of the image takes the guarded one
        for i, used in enumerate(node.input):
            if used == image:
                node.input[i] = guarded
    for output in graph.output:  # (an identity graph would return it)
        if output.name == image:
            raise ValueError(f"the image input of {path} is also an output")
    patch = helper.make_tensor(f"{name}_patch", TensorProto.INT64, [1], [p])
    nodes = [
        helper.make_node("Constant", [], [f"{name}_p"], value=patch),
        helper.make_node("Shape", [image], [f"{name}_bc"], end=2),
        helper.make_node("Shape", [image], [f"{name}_hw"], start=2),
        helper.make_node("Div", [f"{name}_hw", f"{name}_p"], [f"{name}_grid"]),
        helper.make_node("Mul", [f"{name}_grid", f"{name}_p"], [f"{name}_on_grid"]),
        helper.make_node("Concat", [f"{name}_bc", f"{name}_on_grid"], [f"{name}_shape"], axis=0),
        # Off the grid the element counts differ and Reshape fails, naming this node.
        # allowzero: a side below one patch asks for 0 rows, not "keep the input's".
        helper.make_node("Reshape", [image, f"{name}_shape"], [guarded], name=name, allowzero=1),
    ]
    for node in reversed(nodes):
        graph.node.insert(0, node)
    onnx.save(proto, str(path))
