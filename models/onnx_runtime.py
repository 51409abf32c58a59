"""Run an exported segmenter with ONNX Runtime (used by evaluation and prediction)."""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from claravid.models.inputs import check_image_batch

META_PREFIX = "claravid."


def check_onnx_file(path: str | os.PathLike) -> None:
    """Refuse, in one line naming it, a file that cannot be an ONNX model.

    An ONNX file is a protobuf ``ModelProto`` whose first field is ``ir_version`` (tag byte
    0x08), so an empty file, text, or a PyTorch ``.pt`` (a zip archive) is told apart from a
    model before ONNX Runtime reports it as a long internal error.

    Raises:
        FileNotFoundError: no such file.
        ValueError: anything but an ONNX model; the message says what the file holds.
    """
    if os.path.isdir(path):
        raise ValueError(f"ONNX model {path} is a folder; give the .onnx file")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"ONNX model {path} not found; write one with claravid-export")
    with open(path, "rb") as f:
        head = f.read(64)
    if head[:1] == b"\x08":
        return
    if not head:
        what = "is empty"
    elif head.startswith(b"PK\x03\x04") or head[:1] == b"\x80":
        what = "is a PyTorch file, not ONNX (pass it as --checkpoint)"
    elif all(32 <= b < 127 or b in (9, 10, 13) for b in head):
        what = "is a text file"
    else:
        what = "does not hold an ONNX model"
    raise ValueError(f"ONNX model {path} {what}; write one with claravid-export")


class OnnxSegmenter:
    """An exported segmenter: normalised float images [B,3,H,W] -> logits [B,K,H,W] (numpy).

    Args:
        path: The ``.onnx`` file written by `claravid.models.export_onnx`.
        providers: ONNX Runtime execution providers (default: CUDA when available, then CPU).
        threads: Intra-op threads (default: ONNX Runtime's choice).

    Attributes:
        patch_size: H and W must be multiples of it.
        num_classes: K.
        input_size: (H, W) of a fixed-size export, or None when H/W are dynamic.
        model_args: The ``build_model`` arguments of the exported model.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        providers: list[str] | None = None,
        threads: int | None = None,
    ) -> None:
        import onnxruntime as ort

        check_onnx_file(path)
        options = ort.SessionOptions()
        if threads:
            options.intra_op_num_threads = threads
        if providers is None:
            available = ort.get_available_providers()
            providers = [
                p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in available
            ]
        try:
            self.session = ort.InferenceSession(str(path), options, providers=providers)
        except Exception as exc:  # a truncated or damaged file: ORT's message, one line
            reason = str(exc).strip().splitlines()[-1][:200] if str(exc).strip() else ""
            raise ValueError(
                f"{path} cannot be loaded as an ONNX model ({reason}); export it again with "
                "claravid-export"
            ) from None
        self.input_name = self.session.get_inputs()[0].name
        meta = self.session.get_modelmeta().custom_metadata_map
        self.patch_size = int(meta.get(META_PREFIX + "patch_size", 14))
        self.num_classes = int(meta.get(META_PREFIX + "num_classes", 0)) or None
        self.model_args: dict[str, Any] = json.loads(meta.get(META_PREFIX + "model_args", "{}"))
        fixed = meta.get(META_PREFIX + "input_size")
        self.input_size: tuple[int, int] | None = (
            tuple(int(v) for v in fixed.split("x")) if fixed else None  # type: ignore[assignment]
        )

    def check_input(self, images: np.ndarray) -> None:
        """Raise ``TypeError``/``ValueError`` when ``images`` cannot go through this model."""
        check_image_batch(images, self.patch_size, np.ndarray)
        h, w = images.shape[-2:]
        if self.input_size is not None and (h, w) != self.input_size:
            raise ValueError(
                f"this ONNX model was exported for {self.input_size[0]}x{self.input_size[1]} "
                f"inputs, got {h}x{w}: resize/crop to that size or re-export with --dynamic"
            )

    def __call__(self, images: Any) -> np.ndarray:
        """Logits for a batch (numpy array or torch tensor, float32, normalised)."""
        if hasattr(images, "detach"):
            images = images.detach().cpu().numpy()
        self.check_input(images)  # before the cast, so uint8 pixels are refused, not converted
        images = np.ascontiguousarray(images, dtype=np.float32)
        return self.session.run(None, {self.input_name: images})[0]
