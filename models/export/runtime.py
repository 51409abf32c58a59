"""Run an exported segmenter with ONNX Runtime (used by evaluation and prediction)."""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from claravid.models.backbones.specs import BACKBONES
from claravid.models.export.graph_grid import patch_size_from_file
from claravid.models.export.metadata import read_input_size, read_metadata
from claravid.models.inputs import check_image_batch

META_PREFIX = "claravid."

#: ``--provider`` names -> the ONNX Runtime providers tried in order (CPU last, as a fallback
#: for the ops a GPU provider does not implement).
PROVIDERS = {
    "cpu": ["CPUExecutionProvider"],
    "cuda": ["CUDAExecutionProvider", "CPUExecutionProvider"],
    "tensorrt": ["TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"],
}


def resolve_providers(provider: str | None = None) -> list[str]:
    """The ONNX Runtime providers for ``provider`` (``cpu``, ``cuda``, ``tensorrt``).

    None picks the best available of CUDA and CPU. TensorRT is used only when asked: it builds
    an engine per input shape (minutes) before the first window runs.

    Raises:
        ValueError: an unknown name, or a provider this onnxruntime build lacks.
    """
    import onnxruntime as ort

    available = ort.get_available_providers()
    if provider is None:
        provider = "cuda" if "CUDAExecutionProvider" in available else "cpu"
    if provider not in PROVIDERS:
        raise ValueError(f"unknown provider {provider!r}; use one of {', '.join(PROVIDERS)}")
    wanted = PROVIDERS[provider][0]
    if wanted not in available:
        have = ", ".join(k for k, v in PROVIDERS.items() if v[0] in available)
        raise ValueError(
            f"ONNX Runtime provider {provider} is not available here (available: {have}); "
            f"install the onnxruntime build with it (e.g. onnxruntime-gpu) or use --provider cpu"
        )
    return [p for p in PROVIDERS[provider] if p in available]


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
        providers: ONNX Runtime execution providers, or a ``--provider`` name (``cpu``,
            ``cuda``, ``tensorrt``); default: CUDA when available, then CPU.
        threads: Intra-op threads (default: ONNX Runtime's choice).

    Attributes:
        patch_size: H and W must be multiples of it (read from the graph of a file exported
            elsewhere; None when it cannot be told).
        num_classes: K.
        input_size: (H, W) of a fixed-size export, or None when H/W are dynamic.
        model_args: The ``build_model`` arguments of the exported model.
        metadata: The ``claravid`` document (`claravid.models.export.metadata`), or None for a
            file exported elsewhere. The properties below read it (None when absent).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        providers: list[str] | str | None = None,
        threads: int | None = None,
    ) -> None:
        import onnxruntime as ort

        check_onnx_file(path)
        options = ort.SessionOptions()
        if threads:
            options.intra_op_num_threads = threads
        if providers is None or isinstance(providers, str):
            providers = resolve_providers(providers)
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
        self.metadata: dict[str, Any] | None = read_metadata(meta)
        self.num_classes = int(meta.get(META_PREFIX + "num_classes", 0)) or None
        self.model_args: dict[str, Any] = json.loads(meta.get(META_PREFIX + "model_args", "{}"))
        self.patch_size: int | None = _patch_size(meta, self.model_args, path)
        self.input_size: tuple[int, int] | None = read_input_size(meta)
        if self.num_classes is None:  # a foreign file: K from the output shape when static
            dim = self.session.get_outputs()[0].shape[1]
            self.num_classes = dim if isinstance(dim, int) and dim > 0 else None

    def _meta(self, *keys: str) -> Any:
        value: Any = self.metadata
        for key in keys:
            if not isinstance(value, dict):
                return None
            value = value.get(key)
        return value

    @property
    def dtype(self) -> str | None:
        """``fp32``, ``fp16`` or ``int8``."""
        return self._meta("dtype")

    @property
    def palette(self) -> dict[str, Any] | None:
        """``{"name", "names", "colors", "ignore_index"}`` of the classes the ids refer to."""
        return self._meta("palette")

    @property
    def normalisation(self) -> dict[str, Any] | None:
        """``{"mean", "std", "channels", "value_range", "formula"}`` the input expects."""
        return self._meta("normalisation")

    @property
    def window(self) -> tuple[int, int] | None:
        """The validation window (H, W) of the training config."""
        size = self._meta("window", "size")
        return tuple(size) if size else None

    @property
    def stride(self) -> tuple[int, int] | None:
        """The validation window step (H, W) of the training config."""
        stride = self._meta("window", "stride")
        return tuple(stride) if stride else None

    @property
    def scale(self) -> float | None:
        """The resize factor applied to images before the windows."""
        return self._meta("window", "scale")

    @property
    def batch_size(self) -> int | None:
        """Windows per forward pass in the training config's validation."""
        return self._meta("window", "batch_size")

    @property
    def training(self) -> dict[str, Any] | None:
        """``{"step", "config_sha256"}`` of the checkpoint exported."""
        return self._meta("training")

    def check_input(self, images: np.ndarray) -> None:
        """Raise ``TypeError``/``ValueError`` when ``images`` cannot go through this model."""
        norm = self.normalisation or {}
        check_image_batch(
            images, self.patch_size, np.ndarray, mean=norm.get("mean"), std=norm.get("std")
        )
        h, w = images.shape[-2:]
        if self.input_size is not None and (h, w) != self.input_size:
            raise ValueError(
                f"this ONNX model was exported for {self.input_size[1]}x{self.input_size[0]} "
                f"(WxH) inputs, got {w}x{h}: resize/crop to that size or re-export with --dynamic"
            )

    def __call__(self, images: Any) -> np.ndarray:
        """Logits for a batch (numpy array or torch tensor, float32, normalised)."""
        if hasattr(images, "detach"):
            images = images.detach().cpu().numpy()
        self.check_input(images)  # before the cast, so uint8 pixels are refused, not converted
        images = np.ascontiguousarray(images, dtype=np.float32)
        return self.session.run(None, {self.input_name: images})[0]


def _patch_size(
    meta: dict[str, str], model_args: dict[str, Any], path: str | os.PathLike
) -> int | None:
    """The recorded patch size; else the recorded backbone's; else, for a file exported
    elsewhere, the one its graph shows (`patch_size_from_graph`); None when it shows none (the
    window must then be given: nothing is assumed)."""
    if META_PREFIX + "patch_size" in meta:
        return int(meta[META_PREFIX + "patch_size"])
    spec = BACKBONES.get(str(model_args.get("backbone")))
    if spec is not None:
        return spec.patch_size
    return patch_size_from_file(path)
