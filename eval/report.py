"""Per-image results -> the report folder, and back (merge and re-bin without a model).

A report folder holds:

- ``report.json``: ``overall``, ``bins``, ``groups``, ``images``, ``correlation``, ``classes``,
  ``palette``, ``ignore_index``, ``convention``, ``source`` (how the numbers were made: model
  or predictions, data, windows, binning, skipped images);
- ``confusions.npz`` (compressed): per-image confusions with their paths, keys, complexity
  values and units (mission, viewpoint, block, sequence, folder), and with ``--tiles`` every
  tile's image, place, delentropy and confusion (``tile_*``): everything needed to re-bin,
  merge or bootstrap (any ``--cluster`` unit stored there) without the data;
- ``report.md`` and the plots (:mod:`claravid.eval.plots`).

:class:`EvalResult` is the per-image table; :func:`build_report` turns it into the JSON and
:func:`write_outputs` writes the folder.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from claravid.cli import UsageError, atomic_save, atomic_write_text
from claravid.eval.bootstrap import Bootstrap
from claravid.eval.markdown import report_markdown
from claravid.eval.plots import (
    PLOTS,
    plot_bins,
    plot_hardest,
    plot_heatmap,
    plot_scatter,
    plot_tiles,
)
from claravid.eval.stratify import stratify
from claravid.eval.tiles import TileTable, concat_tables, tile_report
from claravid.eval.units import available_units, default_cluster, group_indices, unit_labels

REPORT = "report.json"
CONFUSIONS = "confusions.npz"
KEYS = (
    "overall",
    "bins",
    "groups",
    "images",
    "correlation",
    "classes",
    "palette",
    "ignore_index",
    "convention",
    "source",
    "uncertainty",
    "tiles",
)
#: Keys every report of this tool has (``uncertainty`` came with intervals; ``tiles`` is there
#: with ``--tiles``).
REQUIRED_KEYS = KEYS[:-2]


@dataclass
class EvalResult:
    """One row per image: the input of every report.

    Attributes:
        paths: the RGB file of each image.
        keys: the prediction name of each image.
        confusions: int64 [N,K,K].
        complexity: measure -> float64 [N].
        attributes: unit -> one label per image: ``mission`` / ``viewpoint`` / ``block``
            (ClaraVid), ``sequence`` (UAVid), ``folder``; groups and bootstrap clusters.
        classes: the K class names.
        palette: the palette's name.
        source: where the numbers came from (written to the report as is).
        tiles: every tile's delentropy and confusion (``--tiles``), or None.
    """

    paths: list[str]
    keys: list[str]
    confusions: np.ndarray
    complexity: dict[str, np.ndarray]
    attributes: dict[str, list[str]]
    classes: list[str]
    palette: str
    source: dict[str, Any] = field(default_factory=dict)
    tiles: TileTable | None = None

    def groups(self, by: str | None) -> dict[str, list[int]] | None:
        """Image indices per unit (:func:`claravid.eval.units.group_indices`; None: none)."""
        return None if by is None else group_indices(self.paths, self.attributes, by)

    def units(self) -> list[str]:
        """The cluster units these images carry (``image`` always)."""
        return available_units(self.attributes)

    def cluster_labels(self, unit: str) -> list[str]:
        """The bootstrap cluster of each image for ``unit`` (:func:`unit_labels`)."""
        return unit_labels(self.paths, self.attributes, unit)

    def default_cluster(self) -> str:
        """The dataset's default cluster unit, or the first fallback these images carry."""
        return default_cluster(str(self.source.get("dataset")), self.attributes)


def build_report(
    result: EvalResult,
    *,
    bins: int = 3,
    edges: Sequence[float] | None = None,
    group_by: str | None = None,
    bootstrap: Bootstrap | None = None,
) -> dict[str, Any]:
    """The report's JSON (keys in :data:`KEYS` order); the binning goes under ``source``.

    ``bootstrap`` (default: 1000 resamples, level 0.95, seed 0, the dataset's default cluster
    unit) sets the intervals; its ``cluster`` must be a unit the images carry.
    """
    settings = bootstrap or Bootstrap(cluster=result.default_cluster())
    clusters = result.cluster_labels(settings.cluster)
    numbers = stratify(
        result.paths,
        result.confusions,
        result.classes,
        result.complexity,
        bins=bins,
        edges=edges,
        groups=result.groups(group_by),
        clusters=clusters,
        bootstrap=settings,
    )
    if result.tiles is not None and len(result.tiles):
        numbers["tiles"] = tile_report(
            result.tiles, result.paths, result.classes, bins=bins, edges=edges,
            clusters=clusters, bootstrap=settings,
        )  # fmt: skip
    source = dict(result.source)
    source["binning"] = {**numbers.pop("binning", {}), "group_by": group_by}
    numbers["palette"] = result.palette
    numbers["source"] = source
    return {key: numbers[key] for key in KEYS if key in numbers}


def save_confusions(path: str | Path, result: EvalResult) -> Path:
    """Write the per-image table as a compressed npz (no pickles), atomically."""
    arrays: dict[str, np.ndarray] = {
        "paths": np.asarray(result.paths, dtype=str),
        "keys": np.asarray(result.keys, dtype=str),
        "confusions": np.asarray(result.confusions, dtype=np.int64),
        "classes": np.asarray(result.classes, dtype=str),
        "palette": np.asarray(result.palette, dtype=str),
    }
    for measure, values in result.complexity.items():
        arrays[f"complexity_{measure}"] = np.asarray(values, dtype=np.float64)
    for name, values in result.attributes.items():
        arrays[f"attribute_{name}"] = np.asarray(values, dtype=str)
    if result.tiles is not None:
        tiles = result.tiles
        arrays.update(
            tile_size=np.asarray(tiles.size, dtype=np.int64),
            tile_image=tiles.image.astype(np.int64),
            tile_row=tiles.row.astype(np.int32),
            tile_col=tiles.col.astype(np.int32),
            tile_delent=tiles.delent.astype(np.float64),
            # A tile holds far fewer than 2**31 pixels: int32 halves the file and the memory.
            tile_confusions=tiles.confusions.astype(np.int32),
        )

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)

    return atomic_save(path, write)


def load_result(path: str | Path) -> EvalResult:
    """Read a report folder (or its ``report.json``) back into an :class:`EvalResult`.

    Raises:
        UsageError: not a report folder of this tool, or its files do not agree.
    """
    path = Path(path)
    folder = path.parent if path.name == REPORT or path.suffix == ".json" else path
    report_file, npz_file = folder / REPORT, folder / CONFUSIONS
    if not report_file.is_file() or not npz_file.is_file():
        raise UsageError(
            f"{path} is not a claravid-eval report folder (needs {REPORT} and {CONFUSIONS})"
        )
    report = read_report(report_file)
    try:
        with np.load(npz_file, allow_pickle=False) as npz:
            data = {k: npz[k] for k in npz.files}
        confusions = data["confusions"].astype(np.int64)
        classes = [str(c) for c in data["classes"]]
        result = EvalResult(
            paths=[str(p) for p in data["paths"]],
            keys=[str(k) for k in data["keys"]],
            confusions=confusions,
            complexity={
                k.removeprefix("complexity_"): v.astype(np.float64)
                for k, v in data.items()
                if k.startswith("complexity_")
            },
            attributes={
                k.removeprefix("attribute_"): [str(s) for s in v]
                for k, v in data.items()
                if k.startswith("attribute_")
            },
            classes=classes,
            palette=str(data["palette"]),
            source={k: v for k, v in report["source"].items() if k != "binning"},
            tiles=_load_tiles(data),
        )
    except (KeyError, ValueError, OSError) as exc:
        raise UsageError(f"{npz_file} is damaged or not written by claravid-eval ({exc})") from None
    n, k = len(result.paths), len(classes)
    if confusions.shape != (n, k, k) or classes != list(report["classes"]):
        raise UsageError(f"{npz_file} does not match {report_file} (classes or image count)")
    tiles = result.tiles
    if tiles is not None:
        inside = len(tiles) == 0 or (tiles.image.min() >= 0 and tiles.image.max() < n)
        if tiles.confusions.shape[1:] != (k, k) or not inside:
            raise UsageError(f"{npz_file}: its tiles do not match its images or classes")
    return result


def _load_tiles(data: dict[str, np.ndarray]) -> TileTable | None:
    """The tile table stored in a ``confusions.npz`` (None when it was written without tiles)."""
    if "tile_size" not in data:
        return None
    return TileTable(
        size=int(data["tile_size"]),
        image=data["tile_image"].astype(np.int64),
        row=data["tile_row"].astype(np.int64),
        col=data["tile_col"].astype(np.int64),
        delent=data["tile_delent"].astype(np.float64),
        confusions=data["tile_confusions"].astype(np.int64),
    )


def read_report(path: str | Path) -> dict[str, Any]:
    """Read a ``report.json`` of this tool.

    Raises:
        UsageError: unreadable, not JSON, or JSON of another tool (one line for the user).
    """
    path = Path(path)
    try:
        report = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UsageError(f"cannot read {path} as a claravid-eval report ({exc})") from None
    if not isinstance(report, dict) or not set(REQUIRED_KEYS) <= set(report):
        raise UsageError(
            f"{path} is not a claravid-eval report.json (expected the keys "
            f"{', '.join(REQUIRED_KEYS)})"
        )
    return report


def merge_results(results: Sequence[EvalResult], names: Sequence[str]) -> EvalResult:
    """Join the per-image tables of several runs (job-array parts, or one run to re-bin).

    Raises:
        UsageError: classes or palettes differ, or an image appears in two runs.
    """
    first = results[0]
    seen: dict[str, str] = {}
    for result, name in zip(results, names, strict=True):
        if result.classes != first.classes or result.palette != first.palette:
            raise UsageError(
                f"cannot merge {name} (palette {result.palette}, {len(result.classes)} classes) "
                f"with {names[0]} (palette {first.palette}, {len(first.classes)} classes)"
            )
        for path in result.paths:
            if path in seen:
                raise UsageError(f"{path} is in both {seen[path]} and {name}: merge disjoint runs")
            seen[path] = name
    measures = [m for m in first.complexity if all(m in r.complexity for r in results)]
    attributes = [a for a in first.attributes if all(a in r.attributes for r in results)]
    order = np.argsort(np.asarray([p for r in results for p in r.paths], dtype=str), kind="stable")

    def cat(parts: list[Any]) -> list[Any]:
        flat = [x for part in parts for x in part]
        return [flat[i] for i in order]

    sources = [r.source for r in results]
    source = dict(sources[0]) if len(results) == 1 else {"kind": "merge", "parts": sources}
    source["merged_from"] = [str(n) for n in names]
    return EvalResult(
        paths=cat([r.paths for r in results]),
        keys=cat([r.keys for r in results]),
        confusions=np.concatenate([r.confusions for r in results])[order],
        complexity={m: np.concatenate([r.complexity[m] for r in results])[order] for m in measures},
        attributes={a: cat([r.attributes[a] for r in results]) for a in attributes},
        classes=first.classes,
        palette=first.palette,
        source=source,
        tiles=concat_tables([r.tiles for r in results], [len(r.paths) for r in results], order),
    )


def write_json(path: str | Path, report: dict[str, Any]) -> Path:
    """``report.json``, strict JSON (NaN already written as null), atomically."""
    return atomic_write_text(path, json.dumps(report, indent=2, allow_nan=False) + "\n")


def write_outputs(
    out: str | Path,
    report: dict[str, Any],
    result: EvalResult,
    hardest: Sequence[dict[str, Any]] = (),
    colors: np.ndarray | None = None,
) -> dict[str, Path]:
    """Write the report folder: ``report.json``, ``confusions.npz``, plots, ``report.md``.

    ``report.json`` is written last: it marks the folder as this tool's, complete.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = {"confusions": save_confusions(out / CONFUSIONS, result)}
    plots: dict[str, str] = {}
    if report["bins"]:
        written["bins"] = plot_bins(report, out / PLOTS["bins"])
        written["heatmap"] = plot_heatmap(report, out / PLOTS["heatmap"])
    if "delent" in report["correlation"]:
        written["scatter"] = plot_scatter(report, out / PLOTS["scatter"])
    if hardest and colors is not None:
        written["hardest"] = plot_hardest(hardest, colors, out / PLOTS["hardest"], result.classes)
    tiled = [item for item in hardest if "tiles" in item]
    if tiled:
        written["tiles"] = plot_tiles(tiled, out / PLOTS["tiles"])
    for name in ("bins", "scatter", "heatmap", "hardest", "tiles"):
        if name in written:
            plots[name] = PLOTS[name]
        else:  # a plot of an earlier report in this folder would no longer match it
            (out / PLOTS[name]).unlink(missing_ok=True)
    written["markdown"] = atomic_write_text(out / "report.md", report_markdown(report, plots))
    written["report"] = write_json(out / REPORT, report)
    return written
