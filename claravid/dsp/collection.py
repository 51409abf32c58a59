"""A collection of images -> per-image values -> profile: discovery, workers, cache, shards, JSON.

The JSON is the official script's schema (``metric``, ``num_images``, ``use_blur``,
``blur_ksize``, ``results: [{image_path, complexity}]``) plus ``profile``, ``errors`` and, per
result, the image ``height`` and ``width`` (so profiles of different resolutions can be told
apart). Files written by the official script load too. A large collection splits into shards
(``k/n`` takes every n-th sorted path from the k-th), and :func:`merge_runs` joins the parts.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import warnings
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeGuard

import numpy as np
from tqdm.auto import tqdm

from claravid.dsp.cache import ComplexityCache, cache_key
from claravid.dsp.metrics import (
    ImageReadError,
    check_blur_ksize,
    check_metric,
    gray_complexity,
    preprocess,
    read_gray_views,
)
from claravid.dsp.profile import Profile, fit_profile
from claravid.dsp.tiles import check_tile_size, tile_complexities
from claravid.infra.files import atomic_write_text


class NoImagesError(FileNotFoundError):
    """The input names no image: the message says what was searched and how to fix it."""


@dataclass(frozen=True)
class ImageResult:
    """One image's complexity, with its decoded size (None when read from an official JSON)."""

    image_path: str
    complexity: float
    height: int | None = None
    width: int | None = None


@dataclass(frozen=True)
class ImageError:
    """An image left out of the profile, and why."""

    image_path: str
    error: str


@dataclass
class ProfileRun:
    """Per-image values of one collection and their profile; ``to_json`` gives the file schema."""

    metric: str
    use_blur: bool
    blur_ksize: int
    results: list[ImageResult]
    errors: list[ImageError] = field(default_factory=list)
    shard: dict[str, Any] | None = None
    source: str | None = None
    profile: Profile = field(init=False)  # fitted to the results

    def __post_init__(self) -> None:
        self.profile = fit_profile([r.complexity for r in self.results])

    @property
    def values(self) -> list[float]:
        """The per-image complexities, in result order."""
        return [r.complexity for r in self.results]

    def to_json(self) -> dict[str, Any]:
        """The official schema plus ``profile``, ``errors`` (and ``shard`` for a shard)."""
        results = []
        for r in self.results:
            row: dict[str, Any] = {"image_path": r.image_path, "complexity": r.complexity}
            if r.height is not None:
                row.update(height=r.height, width=r.width)
            results.append(row)
        out: dict[str, Any] = {
            "metric": self.metric,
            "num_images": len(self.results),
            "use_blur": self.use_blur,
            "blur_ksize": self.blur_ksize,
            "results": results,
            "profile": self.profile.to_dict(),
            "errors": [{"image_path": e.image_path, "error": e.error} for e in self.errors],
        }
        if self.shard is not None:
            out["shard"] = self.shard
        return out

    def save(self, path: str | Path) -> Path:
        """Write :meth:`to_json` (strict JSON: no NaN) atomically and return the path."""
        return atomic_write_text(path, json.dumps(self.to_json(), indent=2, allow_nan=False) + "\n")


# ---------------------------------------------------------------------------------------------
# Input discovery and shards


def find_images(input_path: str | Path, pattern: str = "*.jpg") -> list[Path]:
    """Image paths from a directory (glob ``pattern``, ``**`` recurses) or a text file of paths.

    As the official script: a directory is globbed, a file lists one path per line (blank lines
    skipped). A relative listed path is taken from the current directory, as there, or failing
    that from the list file's folder. Paths come back resolved and sorted.

    Raises:
        NoImagesError: the input does not exist, or nothing matched / was listed.
    """
    root = Path(input_path)
    if root.is_dir():
        if not pattern or Path(pattern).is_absolute():
            raise ValueError(
                f"--pattern {pattern!r} must be a non-empty glob relative to {root}, e.g. "
                "'*.jpg' or 'left_rgb/**/*.jpg'"
            )
        found = sorted({p.resolve() for p in root.glob(pattern) if p.is_file()})
        if not found:
            raise NoImagesError(
                f"no files match the pattern {pattern!r} in {root.resolve()}; pass --pattern, "
                "e.g. 'left_rgb/**/*.jpg' for a ClaraVid mission or '**/*.png' to recurse"
            )
        return found
    if root.is_file():
        try:
            text = root.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise NoImagesError(
                f"input {root} is not a text file listing image paths (it is binary, perhaps an "
                f"image): give its folder ({root.parent}) with --pattern, or a list file"
            ) from None
        if "\x00" in text:
            raise NoImagesError(f"input {root} is a binary file, not a text list of image paths")
        lines = [ln.strip() for ln in text.splitlines()]
        paths = []
        for line in filter(None, lines):
            p = Path(line)
            if not p.is_absolute() and not p.exists() and (root.parent / p).exists():
                p = root.parent / p
            paths.append(p.resolve())
        if not paths:
            raise NoImagesError(f"the list file {root.resolve()} names no images (it is empty)")
        return sorted(paths)
    raise NoImagesError(
        f"input {root} does not exist; give a folder of images, a text file with one image "
        "path per line, or a results JSON"
    )


# ---------------------------------------------------------------------------------------------
# Computing values


@dataclass(frozen=True)
class MeasuredImage:
    """One image's values for several measures from one decode, and optionally per tile.

    Attributes:
        image_path: the file.
        values: measure name -> value.
        height, width: the decoded size.
        tiles: delentropy of each tile (float64 [rows, cols], :mod:`claravid.dsp.tiles`), when
            a tile size was given.
    """

    image_path: str
    values: dict[str, float]
    height: int
    width: int
    tiles: np.ndarray | None = None


_Job = tuple[str, tuple[str, ...], bool, int, int | None]
_Output = tuple[str, dict[str, float] | None, int, int, np.ndarray | None, str | None]


def _measure(job: _Job) -> _Output:
    """Decode one image once and compute every measure asked for (and its tiles) from it."""
    path, metrics, blur, ksize, tile_size = job
    try:
        # Whole-image values as the official code reads the file; tiles on the pixels as stored,
        # the ones the labels (and the model) see, so each tile lines up with its confusion.
        gray, stored = read_gray_views(path, stored=tile_size is not None)
        height, width = gray.shape
        values = {}
        if metrics:
            ready = preprocess(gray, blur, ksize)
            values = {m: gray_complexity(ready, m) for m in metrics}
        tiles = None
        if tile_size is not None:
            assert stored is not None  # read with stored=True
            tiles = tile_complexities(stored, tile_size, "delent", blur, ksize)
    except ImageReadError as exc:
        return path, None, 0, 0, None, exc.reason
    except Exception as exc:  # one bad file must never stop a 17k-image run
        return path, None, 0, 0, None, f"{type(exc).__name__}: {exc}"
    return path, values, height, width, tiles, None


def _init_worker() -> None:
    import cv2

    cv2.setNumThreads(1)  # the processes already fill the cores


def compute_measures(
    paths: Iterable[str | Path],
    metrics: Sequence[str] = ("delent",),
    *,
    tile_size: int | None = None,
    blur: bool = True,
    ksize: int = 3,
    workers: int = 0,
    cache: bool | ComplexityCache = True,
    progress: bool = False,
) -> tuple[list[MeasuredImage], list[ImageError]]:
    """Several measures of ``paths`` (in order), each image decoded at most once.

    Values found in the cache (file unchanged) are not recomputed; an image is decoded when any
    of its measures is missing there, or when tiles are asked for (tile values are not cached).

    Args:
        paths: image files.
        metrics: measure names among ``delent``, ``glcment``, ``pixent``.
        tile_size: also the delentropy of each tile of about this many pixels.
        blur: Gaussian blur before measuring (official default on).
        ksize: odd blur kernel size.
        workers: worker processes; 0 or 1 computes in this process.
        cache: True for the default cache, False for none, or a :class:`ComplexityCache`.
        progress: show a progress bar on stderr.

    Returns:
        (results, errors): readable images in input order, and the unreadable ones with reasons.
    """
    metrics = tuple(dict.fromkeys(check_metric(m) for m in metrics))
    if blur:
        check_blur_ksize(ksize)
    if tile_size is not None:
        check_tile_size(tile_size)
    if workers < 0:
        raise ValueError(f"workers must be >= 0 (0 or 1: in this process), got {workers}")
    files = [str(p) for p in paths]
    unique = list(dict.fromkeys(files))
    store = ComplexityCache() if cache is True else (cache or None)
    keys = {(p, m): cache_key(p, m, blur, ksize) for p in unique for m in metrics}
    hits = store.get_many(k for k in keys.values() if k is not None) if store else {}
    known: dict[str, dict[str, float]] = {p: {} for p in unique}
    size: dict[str, tuple[int, int]] = {}
    for (p, m), key in keys.items():
        if key in hits:
            value, h, w = hits[key]
            known[p][m] = value
            size[p] = (h, w)
    jobs = []
    for p in unique:
        missing = tuple(m for m in metrics if m not in known[p])
        if missing or tile_size is not None:
            jobs.append((p, missing, blur, ksize, tile_size))
    tiles: dict[str, np.ndarray | None] = {}
    failed: dict[str, str] = {}
    new_rows = []
    bar = tqdm(total=len(jobs), desc="+".join(metrics), unit="img", disable=not progress)
    try:
        if workers <= 1 or len(jobs) <= 1:
            outputs: Iterable[_Output] = map(_measure, jobs)
            executor = None
        else:
            executor = ProcessPoolExecutor(
                max_workers=workers,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker,
            )
            chunk = max(1, min(16, len(jobs) // (workers * 8)))
            outputs = executor.map(_measure, jobs, chunksize=chunk)
        for path, values, h, w, tile_values, err in outputs:
            if values is None:
                failed[path] = err or "no value"
            else:
                known[path].update(values)
                size[path] = (h, w)
                tiles[path] = tile_values
                new_rows += [(key, v, h, w) for m, v in values.items()
                             if (key := keys[path, m]) is not None]  # fmt: skip
                if len(new_rows) >= 256 and store:
                    store.put_many(new_rows)  # an interrupted run keeps what it measured
                    new_rows = []
            bar.update(1)
    finally:
        bar.close()
        if executor is not None:
            executor.shutdown(cancel_futures=True)
        if store and new_rows:
            store.put_many(new_rows)
    results, errors = [], []
    for p in files:
        if p in failed:
            errors.append(ImageError(p, failed[p]))
        else:
            h, w = size[p]
            values = {m: float(known[p][m]) for m in metrics}
            results.append(MeasuredImage(p, values, h, w, tiles.get(p)))
    return results, errors


def compute_complexities(
    paths: Iterable[str | Path],
    metric: str = "delent",
    *,
    blur: bool = True,
    ksize: int = 3,
    workers: int = 0,
    cache: bool | ComplexityCache = True,
    progress: bool = False,
) -> tuple[list[ImageResult], list[ImageError]]:
    """Per-image values of ``paths`` (in order), reading cached values where the file is unchanged.

    Arguments as :func:`compute_measures`, for one ``metric``.

    Returns:
        (results, errors): readable images in input order, and the unreadable ones with reasons.
    """
    results, errors = compute_measures(
        paths, (metric,), blur=blur, ksize=ksize, workers=workers, cache=cache, progress=progress
    )
    return [ImageResult(r.image_path, r.values[metric], r.height, r.width) for r in results], errors


def profile_images(
    paths: Iterable[str | Path],
    metric: str = "delent",
    *,
    blur: bool = True,
    ksize: int = 3,
    workers: int = 0,
    cache: bool | ComplexityCache = True,
    progress: bool = False,
) -> ProfileRun:
    """Per-image values and the scene profile of a list of images (the demo's entry point).

    Arguments as :func:`compute_complexities`. Unreadable files are listed in ``errors`` and left
    out of the profile; ``run.results``, ``run.profile`` and ``run.values`` hold the rest.
    """
    results, errors = compute_complexities(
        paths, metric, blur=blur, ksize=ksize, workers=workers, cache=cache, progress=progress
    )
    return ProfileRun(metric, blur, ksize, results, errors)


# ---------------------------------------------------------------------------------------------
# JSON in, merge


_FOREIGN_HINT = (
    "expected a JSON object with 'metric' and 'results': [{'image_path', 'complexity'}, ...], "
    "as written by claravid-dsp or the official compute_complexity_profile.py"
)
_ERROR_KEYS = ("image_path", "error")


def _is_int(value: object) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def load_results(path: str | Path) -> ProfileRun:
    """Read a results JSON written by this tool or by the official script (profile refitted).

    Every field is checked, so a JSON file of another program fails here with a message naming
    the file and the first entry that does not fit, not later with a KeyError.

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is a folder, not JSON, or not a results file (the message says which
            entry is wrong and what was expected).
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a folder, not a results JSON; give the .json file")
    if not path.exists():
        raise FileNotFoundError(f"results JSON {path} not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"cannot read results JSON {path}: {exc}") from exc

    def foreign(reason: str) -> ValueError:
        return ValueError(f"{path} is not a complexity results file ({reason}); {_FOREIGN_HINT}")

    if not isinstance(data, dict):
        raise foreign(f"it holds a JSON {type(data).__name__}, not an object")
    if not isinstance(data.get("results"), list):
        raise foreign("no 'results' list")
    metric = data.get("metric", "delent")
    if not isinstance(metric, str):
        raise foreign(f"'metric' is {metric!r}, not a name")
    check_metric(metric)
    use_blur, ksize = data.get("use_blur", True), data.get("blur_ksize", 3)
    if not isinstance(use_blur, bool) or not _is_int(ksize):
        raise foreign(
            f"'use_blur' {use_blur!r} must be true/false and 'blur_ksize' {ksize!r} an int"
        )
    results, errors = [], []
    for i, row in enumerate(data["results"]):
        if not isinstance(row, dict) or not isinstance(row.get("image_path"), str):
            raise foreign(f"results[{i}] is {_short(row)}, not an object with an 'image_path'")
        value = row.get("complexity")
        if value is not None and not _is_number(value):
            raise foreign(f"results[{i}].complexity is {_short(value)}, not a number")
        # The official script writes NaN for images it could not load.
        if value is None or not math.isfinite(value):
            errors.append(ImageError(row["image_path"], "no value in the results file"))
            continue
        size = row.get("height"), row.get("width")
        if size != (None, None) and not all(_is_int(v) and v > 0 for v in size):
            raise foreign(f"results[{i}] has height/width {size}, not positive integers")
        results.append(ImageResult(row["image_path"], float(value), *size))
    listed = data.get("errors", [])
    if not isinstance(listed, list):
        raise foreign(f"'errors' is {_short(listed)}, not a list")
    for i, e in enumerate(listed):
        if not isinstance(e, dict) or not all(isinstance(e.get(k), str) for k in _ERROR_KEYS):
            raise foreign(f"errors[{i}] is {_short(e)}, not an object with 'image_path', 'error'")
        errors.append(ImageError(e["image_path"], e["error"]))
    shard = data.get("shard")
    if shard is not None and not (
        isinstance(shard, dict)
        and _is_int(shard.get("index"))
        and _is_int(shard.get("count"))
        and 0 <= shard["index"] < shard["count"]
    ):
        raise foreign(f"'shard' is {_short(shard)}, not {{'index': k, 'count': n}} with 0 <= k < n")
    return ProfileRun(metric, use_blur, ksize, results, errors, shard=shard, source=str(path))


def _short(value: object, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def merge_runs(runs: Sequence[ProfileRun]) -> ProfileRun:
    """Join shard outputs (or any runs of one setting) into one run with a refitted profile.

    Raises:
        ValueError: settings differ, a shard appears twice, or an image appears in two runs.
    """
    if not runs:
        raise ValueError("nothing to merge: give the shard JSON files")
    first = runs[0]
    settings = (first.metric, first.use_blur, first.blur_ksize if first.use_blur else None)
    for run in runs[1:]:
        other = (run.metric, run.use_blur, run.blur_ksize if run.use_blur else None)
        if other != settings:
            raise ValueError(
                f"cannot merge {run.source} (metric, blur, ksize = {other}) with {first.source} "
                f"({settings}): rerun the shards with the same settings"
            )
    shards = [r.shard for r in runs if r.shard]
    if shards:
        counts = {s["count"] for s in shards}
        if len(counts) > 1:
            raise ValueError(f"shards come from different splits (n = {sorted(counts)})")
        indices = [s["index"] for s in shards]
        dup = sorted({i for i in indices if indices.count(i) > 1})
        if dup:
            raise ValueError(f"shard(s) {dup} given more than once; give each shard's file once")
        missing = sorted(set(range(counts.pop())) - set(indices))
        if missing:
            warnings.warn(
                f"shards {missing} are missing: the merged profile covers only part of the "
                "collection",
                UserWarning,
                stacklevel=2,
            )
    seen: dict[str, str | None] = {}
    results: list[ImageResult] = []
    errors: list[ImageError] = []
    for run in runs:
        for r in run.results:
            if r.image_path in seen:
                raise ValueError(
                    f"{r.image_path} appears in both {seen[r.image_path]} and {run.source}; "
                    "merge the shards of one split only"
                )
            seen[r.image_path] = run.source
            results.append(r)
        errors += run.errors
    results.sort(key=lambda r: r.image_path)
    return ProfileRun(first.metric, first.use_blur, first.blur_ksize, results, errors)
