"""Per-image metrics from a CSV file: the input of ``claravid-eval scores FILE.csv``.

The CSV holds a ``path`` column (relative to the data root, or absolute) and one or more numeric
columns (PSNR, SSIM, a depth error, or the ``images.csv`` of a report: mIoU, mBoundaryIoU, ECE,
cross-view consistency). An empty cell is an image without that value (a frame without a pair):
it is left out of that column's means and correlations. Rows are numbered as a spreadsheet
numbers them, by the file's lines: the header is row 1 and blank lines count (a record after two
blank lines below the header is row 4). Every error names the rows it is about.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from claravid.dsp.measures import METRICS as MEASURES
from claravid.infra.cli import UsageError

PATH_COLUMN = "path"
_SHOWN = 5  # rows named in an error


def _rows(numbers: Sequence[int]) -> str:
    shown = ", ".join(str(n) for n in numbers[:_SHOWN])
    more = f" and {len(numbers) - _SHOWN} more" if len(numbers) > _SHOWN else ""
    return f"row{'s' if len(numbers) > 1 else ''} {shown}{more}"


class MetricsCSV(NamedTuple):
    """A scores CSV: image paths (absolute, normalised, in CSV order), metric column -> float64
    [N], and each image's row as a spreadsheet numbers it (the line it starts on)."""

    paths: list[str]
    metrics: dict[str, np.ndarray]
    rows: list[int]


def _read_records(path: Path) -> tuple[list[str], list[list[str]], list[int]]:
    """Header cells, the non-blank records and the line each starts on (blank lines count)."""
    with open(path, newline="", encoding="utf-8-sig") as f:
        reader = csv.reader(f)
        header = next(reader, [])
        records: list[list[str]] = []
        rows: list[int] = []
        while True:
            start = reader.line_num + 1
            cells = next(reader, None)
            if cells is None:
                return header, records, rows
            if cells:  # a blank line is a row of the file, not a record
                records.append(cells)
                rows.append(start)


def read_metrics_csv(path: str | Path, root: str | Path) -> MetricsCSV:
    """Read a scores CSV.

    Rows are numbered as a spreadsheet numbers them: the header is row 1, blank lines count.

    Args:
        path: the CSV file.
        root: the data root relative paths are taken from.

    Returns:
        ``(paths, metrics, rows)``: absolute, normalised image paths in CSV order, metric
        column -> float64 [N], and each image's row.

    Raises:
        UsageError: unreadable file, no ``path`` column, no metric column, an empty path,
            a non-numeric or non-finite value, a column without any value, or a path listed
            twice (the rows are named).
    """
    path, root = Path(path), Path(root).absolute()
    try:
        raw_names, records, row_numbers = _read_records(path)
        header = [h.strip() for h in raw_names]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise UsageError(f"cannot read the scores CSV {path} ({exc})") from None
    if PATH_COLUMN not in header:
        raise UsageError(
            f"{path} has no '{PATH_COLUMN}' column (header: {', '.join(header) or 'none'}); "
            f"write a header like path,psnr,ssim"
        )
    repeated = sorted({h for h in header if header.count(h) > 1})
    if repeated:
        raise UsageError(
            f"{path}: column {', '.join(repr(h) for h in repeated)} appears more than once in the "
            "header; name each column once"
        )
    taken = [h for h in header if h in MEASURES]
    if taken:
        raise UsageError(
            f"{path}: column {taken[0]!r} is named like a complexity measure (the report's own "
            f"{taken[0]} of each image); rename it (e.g. {taken[0]}_csv)"
        )
    columns = [(j, h) for j, h in enumerate(header) if h != PATH_COLUMN]
    if not columns:
        raise UsageError(f"{path} has no metric column beside '{PATH_COLUMN}' (e.g. psnr)")
    if not records:
        raise UsageError(f"{path} lists no image")
    path_key = header.index(PATH_COLUMN)
    paths: list[str] = []
    metrics = {name: np.empty(len(records)) for _, name in columns}
    empty, bad, extra = [], [], []

    def cell(record: list[str], j: int) -> str:
        return record[j].strip() if j < len(record) else ""

    for i, (record, row) in enumerate(zip(records, row_numbers, strict=True)):
        if len(record) > len(header):  # more cells than header columns
            extra.append(row)
        text = cell(record, path_key)
        if not text:
            empty.append(row)
        file = Path(text).expanduser()
        paths.append(str(Path(_normal(file if file.is_absolute() else root / file))))
        for j, name in columns:
            given = cell(record, j)
            try:
                value = float(given) if given else math.nan  # empty: no value for this image
            except ValueError:
                value = math.nan
            if given and not math.isfinite(value):
                bad.append(f"row {row} {name}={given!r}")
            metrics[name][i] = value
    if extra:
        raise UsageError(f"{path}: more cells than header columns in {_rows(extra)}")
    if empty:
        raise UsageError(f"{path}: empty '{PATH_COLUMN}' in {_rows(empty)}")
    if bad:
        more = f" and {len(bad) - _SHOWN} more" if len(bad) > _SHOWN else ""
        raise UsageError(
            f"{path}: values that are not finite numbers: {', '.join(bad[:_SHOWN])}{more}"
        )
    blank = [name for name, values in metrics.items() if not np.isfinite(values).any()]
    if blank:
        raise UsageError(f"{path}: column {blank[0]!r} has no value in any row; drop it")
    seen: dict[str, int] = {}
    duplicates = []
    for i, p in enumerate(paths):
        if p in seen:
            duplicates.append(f"row {row_numbers[i]} repeats row {row_numbers[seen[p]]}")
        seen.setdefault(p, i)
    if duplicates:
        raise UsageError(
            f"{path}: duplicate paths: {', '.join(duplicates[:_SHOWN])}; give each image once"
        )
    return MetricsCSV(paths, metrics, row_numbers)


def _normal(path: Path) -> str:
    """One spelling per file: absolute, ``..`` and ``.`` resolved, symlinks kept."""
    return os.path.normpath(str(path))


def match_images(
    csv_paths: Sequence[str],
    data_paths: Sequence[str],
    csv_file: Path,
    rows: Sequence[int] | None = None,
) -> list[int]:
    """The data index of each CSV image (``rows``: each one's row, default header + 1 + index).

    Raises:
        UsageError: CSV images that are not in the data (selected split), rows named.
    """
    index = {_normal(Path(p).absolute()): i for i, p in enumerate(data_paths)}
    rows = list(rows) if rows is not None else [i + 2 for i in range(len(csv_paths))]
    missing = [i for i, p in enumerate(csv_paths) if p not in index]
    if missing:
        shown = ", ".join(f"row {rows[i]} {csv_paths[i]}" for i in missing[:3])
        raise UsageError(
            f"{csv_file}: {len(missing)} image(s) are not in the data (root, --dataset, "
            f"--split): {_rows([rows[i] for i in missing])}, e.g. {shown}"
        )
    return [index[p] for p in csv_paths]
