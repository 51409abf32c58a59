"""The report's two files, written atomically and read back checked.

- ``report.json``: ``overall``, ``bins``, ``groups``, ``images``, ``correlation``, ``classes``,
  ``palette``, ``ignore_index``, ``convention``, ``source`` (how the numbers were made: model
  or predictions, data, windows, binning, skipped images), and ``uncertainty`` / ``tiles``
  when computed;
- ``confusions.npz`` (compressed, no pickles): per-image confusions with their paths, keys,
  complexity values and units (mission, viewpoint, block, sequence, folder), and with
  ``--tiles`` every tile's image, place, delentropy and confusion (``tile_*``), and the sums of
  the measures beyond mIoU (``boundary_sums``, ``calibration_sums``, ``pair_*``): everything
  needed to re-bin, merge or bootstrap (any ``--cluster`` unit stored there) without the data.

:func:`load_result` reads a folder back into the per-image table
(:class:`claravid.eval.analysis.table.EvalResult`).
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from claravid.eval.analysis.quality_table import (
    BOUNDARY,
    CALIBRATION,
    COMPUTED,
    CONSISTENCY,
    QUALITY,
    PairTable,
    QualityTable,
    pair_columns,
)
from claravid.eval.analysis.table import EvalResult
from claravid.eval.analysis.tile_bins import TileTable
from claravid.infra.cli import UsageError
from claravid.infra.files import atomic_save, atomic_write_text

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
    "quality",
)
#: Keys every report of this tool has (``uncertainty`` came with intervals; ``tiles`` is there
#: with ``--tiles``; ``quality`` came with the measures beyond mIoU).
REQUIRED_KEYS = KEYS[:-3]
#: Why a report has no measure beyond mIoU: written before they existed.
BEFORE_QUALITY = "the report was written before Boundary IoU, calibration and consistency existed"


def save_confusions(path: str | Path, result: EvalResult, report_id: str | None = None) -> Path:
    """Write the per-image table as a compressed npz (no pickles), atomically, with the
    ``report_id`` of the ``report.json`` it belongs to."""
    arrays: dict[str, np.ndarray] = {
        "paths": np.asarray(result.paths, dtype=str),
        "keys": np.asarray(result.keys, dtype=str),
        "confusions": np.asarray(result.confusions, dtype=np.int64),
        "classes": np.asarray(result.classes, dtype=str),
        "palette": np.asarray(result.palette, dtype=str),
    }
    if report_id is not None:
        arrays["report_id"] = np.asarray(report_id, dtype=str)
    for measure, values in result.complexity.items():
        arrays[f"complexity_{measure}"] = np.asarray(values, dtype=np.float64)
    for name, labels in result.attributes.items():
        arrays[f"attribute_{name}"] = np.asarray(labels, dtype=str)
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
    arrays.update(_quality_arrays(result.quality))

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            # numpy types the names as possible values of its allow_pickle flag; none is.
            np.savez_compressed(f, **arrays)  # type: ignore[arg-type]

    return atomic_save(path, write)


def load_result(path: str | Path) -> EvalResult:
    """Read a report folder (or its ``report.json``) back into an :class:`EvalResult`.

    Raises:
        UsageError: not a report folder of this tool, or its files do not agree.
    """
    path = Path(path)
    folder = path.parent if path.name == REPORT or path.suffix == ".json" else path
    report_file, npz_file = folder / REPORT, folder / CONFUSIONS
    if report_file.is_file() and not npz_file.is_file():
        read_report(report_file)  # a scores report (no confusions) is named as one
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
            source={k: v for k, v in report["source"].items() if k not in ("binning", "report_id")},
            tiles=_load_tiles(data),
            # The real file behind each path: a symlinked or ../ spelling of the data root
            # is the same image (merge refuses it twice, compare pairs it).
            identity=[os.path.realpath(str(p)) for p in data["paths"]],
            lineage=_lineage(report["source"]),
            quality=_load_quality(data, report, len(data["paths"]), len(classes)),
        )
    except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise UsageError(
            f"{npz_file} is damaged or not written by claravid-eval ({exc}); evaluate again"
        ) from None
    # Older reports carry no id; a folder written since carries one in both files.
    ids = (str(data["report_id"]) if "report_id" in data else None,
           report["source"].get("report_id"))  # fmt: skip
    if ids[0] != ids[1]:
        raise UsageError(
            f"{npz_file} does not belong to {report_file} (their report ids differ: the folder "
            "was written by two runs); evaluate or merge into it again"
        )
    n, k = len(result.paths), len(classes)
    if confusions.shape != (n, k, k) or classes != list(report["classes"]):
        raise UsageError(f"{npz_file} does not match {report_file} (classes or image count)")
    tiles = result.tiles
    if tiles is not None:
        inside = len(tiles) == 0 or (tiles.image.min() >= 0 and tiles.image.max() < n)
        if tiles.confusions.shape[1:] != (k, k) or not inside:
            raise UsageError(f"{npz_file}: its tiles do not match its images or classes")
    # A confusion counts pixels: a negative cell is a damaged or edited file, whose mIoU and
    # intervals would be numbers of nothing.
    arrays = {"confusions": confusions}
    if tiles is not None:
        arrays["tile_confusions"] = tiles.confusions
    for name, counts in arrays.items():
        if counts.size and counts.min() < 0:
            where = np.argwhere(counts < 0)
            raise UsageError(
                f"{npz_file} holds {len(where)} negative pixel count(s) in {name} (first: row "
                f"{where[0][0]}), so it was damaged or edited: evaluate again"
            )
    return result


def _quality_arrays(quality: QualityTable | None) -> dict[str, np.ndarray]:
    """The npz arrays of the measures beyond mIoU (none for a measure not computed)."""
    if quality is None:
        return {}
    out = {}
    if quality.boundary is not None:
        out["boundary_sums"] = np.asarray(quality.boundary, dtype=np.int64)
    if quality.calibration is not None:
        out["calibration_sums"] = np.asarray(quality.calibration, dtype=np.float64)
    if quality.pairs is not None:
        pairs = quality.pairs
        out.update(
            pair_next=np.asarray(pairs.next, dtype=str),
            pair_status=np.asarray(pairs.status, dtype=str),
            pair_reason=np.asarray(pairs.reason, dtype=str),
            pair_sums=np.asarray(pairs.sums, dtype=np.int64),
        )
    return out


def _load_quality(
    data: dict[str, np.ndarray], report: dict[str, Any], n: int, k: int
) -> QualityTable:
    """The measures beyond mIoU of a report folder: status from ``report.json``, sums from the
    npz; a report written before them has none (every measure absent)."""
    summary = report.get("quality")
    if not isinstance(summary, dict):
        return QualityTable.absent(BEFORE_QUALITY)
    status = {m: str((summary.get(m) or {}).get("status", "absent")) for m in QUALITY}
    reasons = {m: str(summary[m]["reason"]) for m in QUALITY
               if isinstance(summary.get(m), dict) and summary[m].get("reason")}  # fmt: skip
    settings = {m: dict((summary.get(m) or {}).get("settings") or {}) for m in QUALITY}
    keys = {BOUNDARY: "boundary_sums", CALIBRATION: "calibration_sums", CONSISTENCY: "pair_sums"}
    for name, key in keys.items():
        if (status[name] == COMPUTED) != (key in data):
            raise ValueError(f"report.json says {name} is {status[name]} but the archive "
                             f"{'lacks' if key not in data else 'holds'} {key}")  # fmt: skip
    boundary = data["boundary_sums"].astype(np.int64) if "boundary_sums" in data else None
    calibration = data.get("calibration_sums")
    pairs = None
    if "pair_sums" in data:
        pairs = PairTable([str(x) for x in data["pair_next"]],
                          [str(x) for x in data["pair_status"]],
                          [str(x) for x in data["pair_reason"]],
                          data["pair_sums"].astype(np.int64))  # fmt: skip
    shapes: list[tuple[str, np.ndarray | None, tuple[int, ...]]] = [
        ("boundary_sums", boundary, (n, 2, k))
    ]
    if pairs is not None:
        shapes.append(("pair_sums", pairs.sums, (n, pair_columns(k))))
    if calibration is not None:
        calibration = calibration.astype(np.float64)
        bins = calibration.shape[-1] if calibration.ndim == 3 else -1
        shapes.append(("calibration_sums", calibration, (n, 3, bins)))
    for key, array, shape in shapes:
        if array is not None and array.shape != shape:
            raise ValueError(f"{key} is {array.shape}, expected {shape}")
        if array is not None and array.size and array.min() < 0:
            raise ValueError(f"{key} holds negative sums")
    return QualityTable(status, reasons, boundary, calibration, pairs, settings)


def _lineage(source: dict[str, Any]) -> tuple[str, ...]:
    """The report's own ``report_id`` and the ids it was merged or re-binned from
    (``derived_from``; reports of version 0.1 carry neither)."""
    ids = [source.get("report_id"), *(source.get("derived_from") or [])]
    return tuple(sorted({str(i) for i in ids if isinstance(i, str) and i}))


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
    source = report.get("source") if isinstance(report, dict) else None
    if isinstance(source, dict) and source.get("kind") == "scores":
        metrics = ", ".join(report.get("metrics") or []) or "?"
        raise UsageError(
            f"{path} is a scores report (per-image metrics {metrics}, no mIoU or confusions): "
            "claravid-eval merge and compare take mIoU reports; run claravid-eval scores again "
            "on the merged CSV, or with the other's --edges, and read the metric means side by "
            "side"
        )
    if not isinstance(report, dict) or not set(REQUIRED_KEYS) <= set(report):
        raise UsageError(
            f"{path} is not a claravid-eval report.json (expected the keys "
            f"{', '.join(REQUIRED_KEYS)})"
        )
    return report


def check_report_kind(folder: str | Path, scores: bool, overwrite: bool = False) -> None:
    """Refuse to replace a ``scores`` report with an mIoU report, or the other way round,
    without ``overwrite``: a folder of one kind is not the other's to replace.

    Raises:
        UsageError: ``folder`` holds a report of the other kind and ``overwrite`` is off.
    """
    path = Path(folder) / REPORT
    if overwrite or not path.is_file():
        return
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
        kind = old["source"]["kind"]
    except (OSError, ValueError, KeyError, TypeError):
        return  # not readable as a report: check_output_dir's marker rule applies
    if (kind == "scores") != scores:
        held = "a scores report" if kind == "scores" else "an mIoU report"
        new = "a scores report" if scores else "an mIoU report"
        raise UsageError(
            f"output {folder} holds {held}; writing {new} there would replace it: choose a new "
            "folder or pass --overwrite"
        )


def write_json(path: str | Path, report: dict[str, Any]) -> Path:
    """``report.json``, strict JSON (NaN already written as null), atomically."""
    return atomic_write_text(path, json.dumps(report, indent=2, allow_nan=False) + "\n")
