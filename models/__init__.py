"""Models: DINOv2 and DINOv3 ViT backbones in plain PyTorch, segmentation heads (DPT, linear,
UperNet), ONNX export.

Public API::

    BACKBONES / backbone_spec(name)          # what each named backbone is (backbones.py)
    build_backbone(name, weights=None)       # DINOv2 ViT-S/B/L/g (+ _reg), DINOv3 ViT-S/S+/B/
                                             # L/H+/7B (+ _sat); official or Hugging Face weights
    HEADS / head_spec(name)                  # the heads and their settings (heads.py)
    build_model(backbone, num_classes, head="dpt", ...)  # frozen backbone + trainable head
    save_checkpoint / load_checkpoint        # weights_only-safe model files
    export_onnx(model, path, ExportSettings(...))  # ONNX + onnxruntime check
    OnnxSegmenter(path)                      # onnxruntime runner

Names are imported on first use (PEP 562): a module that needs only the ONNX Runtime side
(``claravid.models.onnx_runtime``, ``claravid.models.onnx_metadata``) does not load torch.
"""

from __future__ import annotations

import importlib
from typing import Any

# Public name -> module that defines it.
_LAZY = {
    "BACKBONES": "claravid.models.backbones",
    "BACKBONE_NAMES": "claravid.models.backbones",
    "BackboneSpec": "claravid.models.backbones",
    "backbone_config": "claravid.models.backbones",
    "backbone_spec": "claravid.models.backbones",
    "build_backbone": "claravid.models.build",
    "CheckpointError": "claravid.models.checkpoint",
    "load_checkpoint": "claravid.models.checkpoint",
    "save_checkpoint": "claravid.models.checkpoint",
    "DinoV3VisionTransformer": "claravid.models.dinov3",
    "DPTHead": "claravid.models.dpt",
    "HEAD_NAMES": "claravid.models.heads",
    "HEADS": "claravid.models.heads",
    "HeadSpec": "claravid.models.heads",
    "head_spec": "claravid.models.heads",
    "LinearHead": "claravid.models.linear_head",
    "ExportCheckError": "claravid.models.export",
    "export_onnx": "claravid.models.export",
    "ExportSettings": "claravid.models.export",
    "Provenance": "claravid.models.export",
    "NotEnoughMemoryError": "claravid.models.memory",
    "OnnxSegmenter": "claravid.models.onnx_runtime",
    "InputRangeWarning": "claravid.models.inputs",
    "Segmenter": "claravid.models.segmenter",
    "build_model": "claravid.models.segmenter",
    "UperNetHead": "claravid.models.upernet",
    "DinoVisionTransformer": "claravid.models.vit",
    "WeightsError": "claravid.models.weights",
    "hf_to_official": "claravid.models.weights",
    "official_to_hf": "claravid.models.weights",
    "official_url": "claravid.models.weights",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'claravid.models' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
