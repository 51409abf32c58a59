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
    """The Hugging Face hub cache: ``huggingface_hub``'s own ``constants.HF_HUB_CACHE`` (from
    ``HF_HUB_CACHE``, the legacy ``HUGGINGFACE_HUB_CACHE``, ``HF_HOME``, ``XDG_CACHE_HOME``, as
    that version reads them), so the toolkit reads where ``hf download`` writes. Without
    ``huggingface_hub`` (the message that says to install it still names the place), the same
    order restated."""
    try:
        from huggingface_hub import constants
    except ImportError:
        env = os.environ
        home = env.get("HF_HOME") or os.path.join(
            env.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"),
            "huggingface",
        )
        hub = env.get("HF_HUB_CACHE") or env.get("HUGGINGFACE_HUB_CACHE")
        return Path(os.path.expandvars(os.path.expanduser(hub or os.path.join(home, "hub"))))
    return Path(constants.HF_HUB_CACHE)


def _holds(folder: Path, patterns: list[str]) -> bool:
    return any(f.is_file() for p in patterns for f in folder.glob(p))


def _offline() -> bool:
    """``HF_HUB_OFFLINE`` as set now, or as ``huggingface_hub`` read it at import."""
    if os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in {"1", "true", "yes", "on"}:
        return True
    try:
        from huggingface_hub import constants
    except ImportError:
        return False
    return bool(constants.HF_HUB_OFFLINE)


def repo_folder_snapshot(folder: Path) -> Path | None:
    """The snapshot a hub-cache repository folder (``models--org--name``, what the offline
    message says to copy) points to through ``refs/main``; None for any other folder.

    Raises:
        WeightsError: ``refs/main`` names a snapshot the folder does not hold (a partial copy).
    """
    ref = folder / "refs" / "main"
    if not folder.name.startswith("models--") or not ref.is_file():
        return None
    snapshot = folder / "snapshots" / ref.read_text().strip()
    if not snapshot.is_dir():
        repo = folder.name.removeprefix("models--").replace("--", "/")
        raise WeightsError(
            f"{folder}: refs/main names the snapshot {snapshot.name}, which is not in "
            f"{folder / 'snapshots'}: the copy or download is incomplete; resume it with "
            f"`hf download {repo}` and copy the whole folder again"
        )
    return snapshot


def incomplete_download(folder: Path, repo_id: str | None) -> WeightsError | None:
    """The error for a hub snapshot whose download stopped half-way: a weights link that points
    to no file (the blob never arrived), or configs without any weights file; None otherwise."""
    resume = (
        f"resume it with `hf download {repo_id}` (it fetches only what is missing)"
        if repo_id
        else "resume the download (`hf download <repo id>` fetches only what is missing)"
    )
    dangling = sorted(f.name for f in folder.glob("*") if f.is_symlink() and not f.exists())
    if dangling:
        return WeightsError(
            f"{folder}: {', '.join(dangling)} point(s) to a file that is not there: the download "
            f"is incomplete; {resume}"
        )
    weights = [f for f in folder.iterdir() if f.is_file() and f.suffix in _WEIGHT_SUFFIXES]
    if not weights and (folder / "config.json").is_file() and "snapshots" in folder.parts:
        return WeightsError(
            f"{folder} holds config.json but no weights file: the download is incomplete; {resume}"
        )
    return None


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
    cached = None
    for patterns in _PATTERNS:
        try:
            cached = huggingface_hub.snapshot_download(
                repo_id, cache_dir=cache, local_files_only=True, allow_patterns=patterns
            )
        except LocalEntryNotFoundError:
            continue
        if _holds(Path(cached), patterns[1:]):
            return Path(cached)
    incomplete = incomplete_download(Path(cached), repo_id) if cached else None
    if incomplete is not None and _offline():
        raise incomplete
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
