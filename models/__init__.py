"""Models: DINOv2 ViT backbones in plain PyTorch, the DPT segmentation decoder, ONNX export.

Public API::

    build_backbone(name, weights=None)      # DINOv2 ViT-S/B/L/g (+ _reg), official or HF weights
    build_model(backbone, num_classes, ...)  # frozen backbone + trainable DPT head
    save_checkpoint / load_checkpoint        # weights_only-safe model files
    export_onnx(model, path, ...)            # ONNX + onnxruntime check
    OnnxSegmenter(path)                      # onnxruntime runner
"""

from claravid.models.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from claravid.models.dpt import DPT_DEFAULTS, DPTHead
from claravid.models.export import ExportCheckError, export_onnx
from claravid.models.onnx_runtime import OnnxSegmenter
from claravid.models.segmenter import Segmenter, build_model
from claravid.models.vit import (
    BACKBONE_NAMES,
    DinoVisionTransformer,
    backbone_config,
    build_backbone,
)
from claravid.models.weights import WeightsError, hf_to_official, official_to_hf, official_url

__all__ = [
    "BACKBONE_NAMES",
    "DPT_DEFAULTS",
    "CheckpointError",
    "DPTHead",
    "DinoVisionTransformer",
    "ExportCheckError",
    "OnnxSegmenter",
    "Segmenter",
    "WeightsError",
    "backbone_config",
    "build_backbone",
    "build_model",
    "export_onnx",
    "hf_to_official",
    "load_checkpoint",
    "official_to_hf",
    "official_url",
    "save_checkpoint",
]
