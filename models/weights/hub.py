"""Where weights come from besides a local path: the official DINOv2 download, and repositories
of the Hugging Face hub (``timm/...``, ``facebook/...``) through ``huggingface_hub``'s cache.

A hub id is read from the local cache first, so a machine without network uses what was
downloaded before (set ``HF_HUB_OFFLINE=1`` to forbid any look-up). Otherwise the repository's
weights and ``config.json`` are downloaded into that cache, once. ``huggingface_hub`` is an
optional dependency (the ``hub`` extra); without it a hub id is an error that says how to get it.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import torch

from claravid.models.backbones.specs import DINOV3_REQUEST_URL, BackboneSpec, backbone_spec
from claravid.models.weights.formats import WeightsError

#: What is fetched of a hub repository: the weights (safetensors first) and the configs.
_PATTERNS = (["*.json", "*.safetensors"], ["*.json", "*.bin", "*.pth"])
_HUB_ID = re.compile(r"[A-Za-z0-9][\w.-]*/[A-Za-z0-9][\w.-]*")
_WEIGHT_SUFFIXES = (".pth", ".pt", ".bin", ".safetensors")


def licence_gated(spec: BackboneSpec) -> WeightsError:
    """The one-line error for ``weights="official"`` where the files cannot be downloaded."""
    timm = next((h for h in spec.weights.hub if h.startswith("timm/")), None)
    ungated = f", or use timm's ungated copy: weights={timm!r}" if timm else ""
    return WeightsError(
        f"the official {spec.family_name} weights are licence-gated and cannot be downloaded "
        f"here: accept the licence at {DINOV3_REQUEST_URL} (the download URLs come by e-mail), "
        f"fetch {spec.weights.file} and pass its path as weights=... "
        f"(claravid-train: model.weights=PATH){ungated}"
    )


def official_url(name: str) -> str:
    """URL of the official checkpoint of a backbone name such as ``dinov2_vitl14_reg``.

    Raises:
        WeightsError: the backbone's weights are licence-gated (DINOv3): there is no public URL.
    """
    spec = backbone_spec(name)
    if spec.weights.url is None:
        raise licence_gated(spec)
    return spec.weights.url


def official_checkpoint_path(name: str) -> Path:
    """Where the official checkpoint of ``name`` lives in the torch hub cache."""
    return Path(torch.hub.get_dir()) / "checkpoints" / backbone_spec(name).weights.file


def download_official(name: str) -> Path:
    """Return the cached official checkpoint, downloading it once.

    Raises:
        WeightsError: the weights are licence-gated (DINOv3): nothing to download.
        ConnectionError: when offline, naming the URL and where to put the file by hand.
    """
    url = official_url(name)
    target = official_checkpoint_path(name)
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        torch.hub.download_url_to_file(url, str(target), progress=True)
    except Exception as exc:
        raise ConnectionError(
            f"could not download the official {name} weights from {url} ({exc}). "
            f"Download that file on a connected machine and put it at {target} "
            "(or pass its local path as weights=...)"
        ) from exc
    return target


def is_hub_id(weights: str) -> bool:
    """Whether ``weights`` reads as a hub repository id (``owner/name``) rather than a path.

    Callers try it as a path first: an existing ``owner/name`` folder is a folder.
    """
    return bool(_HUB_ID.fullmatch(weights)) and not weights.endswith(_WEIGHT_SUFFIXES)


def hub_cache_dir() -> Path:
    """The Hugging Face hub cache, as ``huggingface_hub`` would resolve it now."""
    if os.environ.get("HF_HUB_CACHE"):
        return Path(os.environ["HF_HUB_CACHE"])
    if os.environ.get("HF_HOME"):
        return Path(os.environ["HF_HOME"]) / "hub"
    return Path.home() / ".cache" / "huggingface" / "hub"


def _holds(folder: Path, patterns: list[str]) -> bool:
    return any(next(folder.glob(p), None) is not None for p in patterns)


def _offline() -> bool:
    return os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in {"1", "true", "yes", "on"}


def hub_snapshot(repo_id: str) -> Path:
    """The local folder of hub repository ``repo_id``: from the cache, else downloaded into it.

    Raises:
        WeightsError: ``huggingface_hub`` is not installed; the repository is not cached and
            cannot be fetched (offline, unknown, licence-gated): one line each, saying what to
            download and where.
    """
    cache = hub_cache_dir()
    fetch_by_hand = (
        f"on a connected machine run `hf download {repo_id}` and copy "
        f"{cache / ('models--' + repo_id.replace('/', '--'))} to the same place here, or pass "
        "the downloaded folder's path"
    )
    try:
        import huggingface_hub
        from huggingface_hub.errors import GatedRepoError, LocalEntryNotFoundError
    except ImportError:
        raise WeightsError(
            f"weights={repo_id!r} is a Hugging Face hub id, and reading one needs "
            "huggingface_hub: pip install 'claravid[hub]', or download the repository and pass "
            "its folder"
        ) from None
    for patterns in _PATTERNS:
        try:
            folder = huggingface_hub.snapshot_download(
                repo_id, cache_dir=cache, local_files_only=True, allow_patterns=patterns
            )
        except LocalEntryNotFoundError:
            continue
        if _holds(Path(folder), patterns[1:]):
            return Path(folder)
    if _offline():
        raise WeightsError(
            f"weights={repo_id!r}: no such file or folder, and the Hugging Face cache ({cache}) "
            f"does not hold that repository while HF_HUB_OFFLINE is set: {fetch_by_hand}"
        )
    error = ""
    for patterns in _PATTERNS:
        try:
            folder = huggingface_hub.snapshot_download(
                repo_id, cache_dir=cache, allow_patterns=patterns
            )
        except GatedRepoError:
            raise WeightsError(
                f"weights={repo_id!r} is licence-gated on the Hugging Face hub: accept the "
                f"licence at https://huggingface.co/{repo_id} and log in (`hf auth login`), "
                "or pass a downloaded file or folder"
            ) from None
        except Exception as exc:  # offline, unknown repository, server error
            error = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
            break
        if _holds(Path(folder), patterns[1:]):
            return Path(folder)
    raise WeightsError(
        f"weights={repo_id!r}: no such file or folder, and the Hugging Face hub repository "
        f"could not be fetched into {cache} ({error or 'it holds no weights file'}): "
        f"{fetch_by_hand}"
    )
