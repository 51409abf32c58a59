"""Models: DINOv2 and DINOv3 ViT backbones in plain PyTorch, segmentation heads (DPT, linear,
UperNet), ONNX export.

Public API (24 names, one per concept; everything else is imported from its room)::

    BACKBONES / backbone_spec(name)          # what each named backbone is (backbones/specs.py)
    build_backbone(name, weights=None)       # DINOv2 ViT-S/B/L/g (+ _reg), DINOv3 ViT-S/S+/B/
                                             # L/H+/7B (+ _sat); official or Hugging Face weights
    HEADS / head_spec(name)                  # the heads and their settings (heads/specs.py)
    DPTHead / LinearHead / UperNetHead       # the heads (heads/protocol.py: what one provides)
    build_model(backbone, num_classes, head="dpt", ...)  # frozen backbone + trainable head
    save_checkpoint / load_checkpoint        # weights_only-safe model files
    export_onnx(model, path, ExportSettings(...))  # ONNX + onnxruntime check
    OnnxSegmenter(path)                      # onnxruntime runner

Rooms: ``layers/`` (attention, RoPE, blocks), ``backbones/`` (the ViT trunk, the DINOv2 and
DINOv3 families, the `Backbone` protocol), ``heads/`` (DPT, linear, UperNet, the `Head`
protocol), ``weights/`` (one loader, each family's key renames official <-> Hugging Face <->
timm), ``export/`` (ONNX, fp16, int8, metadata, runtime).

Names are imported on first use (PEP 562): a module that needs only the ONNX Runtime side
(``claravid.models.export.runtime``, ``claravid.models.export.metadata``) does not load torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from claravid.infra.lazy import lazy_exports

__all__ = [
    "BACKBONES",
    "HEADS",
    "BackboneSpec",
    "CheckpointError",
    "DPTHead",
    "ExportCheckError",
    "ExportSettings",
    "HeadSpec",
    "InputRangeWarning",
    "LinearHead",
    "NotEnoughMemoryError",
    "OnnxSegmenter",
    "Provenance",
    "Segmenter",
    "UperNetHead",
    "WeightsError",
    "backbone_spec",
    "build_backbone",
    "build_model",
    "export_onnx",
    "head_spec",
    "load_checkpoint",
    "official_url",
    "save_checkpoint",
]

if TYPE_CHECKING:
    from claravid.models.backbones.build import build_backbone
    from claravid.models.backbones.memory import NotEnoughMemoryError
    from claravid.models.backbones.specs import BACKBONES, BackboneSpec, backbone_spec
    from claravid.models.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
    from claravid.models.export.onnx import (
        ExportCheckError,
        ExportSettings,
        Provenance,
        export_onnx,
    )
    from claravid.models.export.runtime import OnnxSegmenter
    from claravid.models.heads.dpt import DPTHead
    from claravid.models.heads.linear import LinearHead
    from claravid.models.heads.specs import HEADS, HeadSpec, head_spec
    from claravid.models.heads.upernet import UperNetHead
    from claravid.models.inputs import InputRangeWarning
    from claravid.models.segmenter import Segmenter, build_model
    from claravid.models.weights.loader import WeightsError, official_url
else:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "BACKBONES": "claravid.models.backbones.specs",
            "BackboneSpec": "claravid.models.backbones.specs",
            "backbone_spec": "claravid.models.backbones.specs",
            "build_backbone": "claravid.models.backbones.build",
            "CheckpointError": "claravid.models.checkpoint",
            "load_checkpoint": "claravid.models.checkpoint",
            "save_checkpoint": "claravid.models.checkpoint",
            "DPTHead": "claravid.models.heads.dpt",
            "HEADS": "claravid.models.heads.specs",
            "HeadSpec": "claravid.models.heads.specs",
            "head_spec": "claravid.models.heads.specs",
            "LinearHead": "claravid.models.heads.linear",
            "InputRangeWarning": "claravid.models.inputs",
            "UperNetHead": "claravid.models.heads.upernet",
            "ExportCheckError": "claravid.models.export.onnx",
            "export_onnx": "claravid.models.export.onnx",
            "ExportSettings": "claravid.models.export.onnx",
            "Provenance": "claravid.models.export.onnx",
            "NotEnoughMemoryError": "claravid.models.backbones.memory",
            "OnnxSegmenter": "claravid.models.export.runtime",
            "Segmenter": "claravid.models.segmenter",
            "build_model": "claravid.models.segmenter",
            "WeightsError": "claravid.models.weights.loader",
            "official_url": "claravid.models.weights.loader",
        },
    )
