"""The report's pictures (matplotlib, no display needed), each written atomically.

- ``miou_per_bin.png``: mIoU per complexity bin, bars labelled with their delentropy ranges,
  error bars = the bootstrap intervals;
- ``miou_vs_delent.png``: per-image mIoU against delentropy, with a least-squares line;
- ``class_iou_per_bin.png``: per-class IoU per bin as a heat map (blank: class absent);
- ``hardest.png``: the k images of lowest mIoU, image | ground truth | prediction; then the k
  cross-view pairs of lowest consistency, frame t with its kept pixels marked (green: the
  predictions of t and s agree, red: they disagree) | frame s | the prediction of t;
- ``tiles.png`` (``--tiles``): the same images, image | delentropy per tile (one colour scale
  for all) | error pixels: where the model fails next to where the scene is complex;
- ``compare.png`` (``compare``): the mIoU per bin of several reports side by side, with
  their intervals;
- ``scores`` reports: ``<metric>_per_bin.png`` (mean per bin with intervals) and
  ``<metric>_vs_delent.png`` (per image, with the fitted line).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from claravid.infra.files import atomic_save

#: Colours of a pair's marks: kept and agreeing (green), kept and disagreeing (red).
AGREE, DISAGREE = np.array([44, 160, 44], np.uint8), np.array([214, 39, 40], np.uint8)

PLOTS = {
    "bins": "miou_per_bin.png",
    "scatter": "miou_vs_delent.png",
    "heatmap": "class_iou_per_bin.png",
    "hardest": "hardest.png",
    "tiles": "tiles.png",
}


def save_figure(fig: Figure, path: str | Path, dpi: int = 100) -> Path:
    """Save ``fig`` as ``path`` atomically."""
    return atomic_save(path, lambda tmp: fig.savefig(tmp, dpi=dpi))


def _fmt(value: float | None, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def error_bars(values: Sequence[float], rows: Sequence[dict[str, Any]], key: str) -> np.ndarray:
    """Matplotlib ``yerr`` [2, n] of the intervals ``row[key]`` around ``values`` (0: none)."""
    err = np.zeros((2, len(rows)))
    for i, (value, row) in enumerate(zip(values, rows, strict=True)):
        ci = row.get(key)
        if ci and np.isfinite(value):
            # Percentile intervals need not contain the estimate; clip to draw non-negative bars.
            err[:, i] = max(0.0, value - ci[0]), max(0.0, ci[1] - value)
    return err


def bin_label(row: dict[str, Any]) -> str:
    """``low\\n[3.10, 4.20]\\nn=12``: a bin's name, delentropy range and size."""
    return f"{row['name']}\n[{_fmt(row.get('lo'))}, {_fmt(row.get('hi'))}]\nn={row['num_images']}"


def plot_bins(report: dict[str, Any], path: str | Path) -> Path:
    """Bars of mIoU per bin, with the overall mIoU as a dashed line."""
    rows = report["bins"]
    fig = Figure(figsize=(max(5, 1.6 * len(rows) + 2), 4), layout="constrained")
    ax = fig.subplots()
    values = [np.nan if r["miou"] is None else r["miou"] for r in rows]
    bars = ax.bar(range(len(rows)), values, color="tab:blue",
                  yerr=error_bars(values, rows, "miou_ci"), capsize=6)  # fmt: skip
    ax.bar_label(bars, labels=[_fmt(r["miou"], 3) for r in rows], padding=2)
    ax.set_xticks(range(len(rows)), [bin_label(r) for r in rows])
    overall = report["overall"]["miou"]
    if overall is not None:
        ax.axhline(overall, color="k", ls="--", lw=1, label=f"overall {overall:.3f}")
        ax.legend(loc="upper right")
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("mIoU")
    ax.set_xlabel("delentropy bin")
    ax.set_title("mIoU per complexity bin")
    return save_figure(fig, path)


def _scatter(
    x: np.ndarray, y: np.ndarray, corr: dict[str, Any], title: str, xlabel: str, ylabel: str,
    fit_format: str,
) -> Figure:  # fmt: skip
    """Points (x, y) with finite values, the least-squares line, Pearson/Spearman and n."""
    keep = np.isfinite(x) & np.isfinite(y)
    fig = Figure(figsize=(6, 4.5), layout="constrained")
    ax = fig.subplots()
    ax.scatter(x[keep], y[keep], s=14, alpha=0.7)
    if keep.sum() >= 2 and np.ptp(x[keep]) > 0:
        slope, intercept = np.polyfit(x[keep], y[keep], 1)
        xs = np.linspace(x[keep].min(), x[keep].max(), 50)
        ax.plot(xs, slope * xs + intercept, color="tab:red",
                label=f"fit: {slope:{fit_format}} per bit")  # fmt: skip
        ax.legend(loc="best")
    ax.set_title(
        f"{title}: Pearson {_fmt(corr.get('pearson'))}, "
        f"Spearman {_fmt(corr.get('spearman'))}, n={corr.get('n', int(keep.sum()))}"
    )
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    return fig


def plot_scatter(report: dict[str, Any], path: str | Path, measure: str = "delent") -> Path:
    """Per-image mIoU against ``measure``, the fitted line, and Pearson/Spearman in the title."""
    x = np.array([np.nan if r.get(measure) is None else r[measure] for r in report["images"]])
    y = np.array([np.nan if r["miou"] is None else r["miou"] for r in report["images"]])
    fig = _scatter(x, y, report["correlation"].get(measure, {}), f"per-image mIoU vs {measure}",
                   f"{measure} (bits)", "mIoU", "+.3f")  # fmt: skip
    fig.axes[0].set_ylim(-0.02, 1.02)
    return save_figure(fig, path)


def plot_heatmap(report: dict[str, Any], path: str | Path) -> Path:
    """Per-class IoU (rows) per bin (columns); absent classes blank."""
    rows, classes = report["bins"], report["classes"]
    grid = np.array(
        [[np.nan if r["per_class_iou"][c] is None else r["per_class_iou"][c] for r in rows]
         for c in classes]
    )  # fmt: skip
    fig = Figure(
        figsize=(2 + 1.3 * max(1, len(rows)), 1 + 0.35 * len(classes)), layout="constrained"
    )
    ax = fig.subplots()
    image = ax.imshow(np.ma.masked_invalid(grid), vmin=0, vmax=1, cmap="viridis", aspect="auto")
    for (i, j), value in np.ndenumerate(grid):
        if np.isfinite(value):
            ax.text(j, i, f"{value:.2f}", ha="center", va="center", fontsize=8,
                    color="white" if value < 0.5 else "black")  # fmt: skip
    ax.set_xticks(
        range(len(rows)), [f"{r['name']}\n[{_fmt(r.get('lo'))}, {_fmt(r.get('hi'))}]" for r in rows]
    )
    ax.set_yticks(range(len(classes)), classes)
    fig.colorbar(image, ax=ax, label="IoU")
    ax.set_title("IoU per class and complexity bin")
    return save_figure(fig, path)


def plot_hardest(
    items: Sequence[dict[str, Any]],
    colors: np.ndarray,
    path: str | Path,
    names: Sequence[str] | None = None,
) -> Path:
    """One row per image: the RGB, its ground truth and the prediction, in palette colours.

    Args:
        items: ``{"image": uint8 H×W×3, "mask": uint8 H×W, "prediction": uint8 H×W,
            "title": str}``, hardest first.
        colors: the palette's K×3 colours; ignored pixels are drawn white (black is a class
            colour in several palettes, e.g. UAVid's Clutter).
        path: the PNG to write.
        names: the K class names: a legend of the colours below the rows.
    """
    return save_figure(hardest_figure(items, colors, names), path, dpi=80)


def hardest_figure(
    items: Sequence[dict[str, Any]], colors: np.ndarray, names: Sequence[str] | None = None
) -> Figure:
    """The figure of `plot_hardest`: with ``names``, a legend of the classes shown in it."""
    table = np.full((256, 3), 255, dtype=np.uint8)
    table[: len(colors)] = colors
    fig = Figure(figsize=(12, 3.2 * len(items)), layout="constrained")
    axes = fig.subplots(len(items), 3, squeeze=False)
    for row, item in zip(axes, items, strict=True):
        if "agree" in item:  # a cross-view pair of low consistency
            panels = (mark_pair(item["image"], item["kept"], item["agree"]), item["next_image"],
                      table[item["prediction"]])  # fmt: skip
            titles = (item["title"], "next frame s", "prediction of t")
        else:
            panels = (item["image"], table[item["mask"]], table[item["prediction"]])
            titles = (item["title"], "ground truth", "prediction")
        for ax, panel, name in zip(row, panels, titles, strict=True):
            ax.imshow(panel, interpolation="nearest")
            ax.set_axis_off()
            ax.set_title(name, fontsize=9)
    if names is not None:
        shown = np.unique(np.concatenate([
            np.concatenate([i["mask"].ravel(), i["prediction"].ravel()]) for i in items
        ]))  # fmt: skip
        handles = [
            Patch(facecolor=table[k] / 255, edgecolor="grey", label=names[k])
            for k in shown
            if k < len(names)
        ]
        if (shown >= len(names)).any():
            handles.append(Patch(facecolor="white", edgecolor="grey", label="ignored"))
        fig.legend(handles=handles, loc="outside lower center", ncol=min(6, len(handles)),
                   fontsize=9, frameon=False)  # fmt: skip
    return fig


def mark_pair(image: np.ndarray, kept: np.ndarray, agree: np.ndarray) -> np.ndarray:
    """Frame t's thumbnail (uint8 H×W×3) with its kept pixels tinted: green where the
    predictions of t and s agree, red where they disagree; other pixels unchanged."""
    out = image.astype(np.float32)
    for mask, colour in ((kept & agree, AGREE), (kept & ~agree, DISAGREE)):
        out[mask] = 0.45 * out[mask] + 0.55 * colour
    return out.round().astype(np.uint8)


def plot_tiles(items: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """One row per image: the RGB, its tiles' delentropy, its error pixels.

    Args:
        items: ``{"image": uint8 H×W×3, "tiles": float [R, C], "errors": uint8 H×W (1 wrong,
            0 right, 2 ignored), "title": str}``, hardest first; the tile map is drawn over
            the image's extent (tiles of unequal size by at most a pixel, drawn equal).
        path: the PNG to write.
    """
    values = np.concatenate([np.ravel(i["tiles"]) for i in items])
    lo, hi = float(np.nanmin(values)), float(np.nanmax(values))
    fig = Figure(figsize=(12, 3.2 * len(items) + 0.6), layout="constrained")
    axes = fig.subplots(len(items), 3, squeeze=False)
    # Errors: right = light grey, wrong = red, ignored = white.
    shades = np.array([[215, 215, 215], [214, 39, 40], [255, 255, 255]], dtype=np.uint8)
    shown = None
    for row, item in zip(axes, items, strict=True):
        h, w = item["image"].shape[:2]
        row[0].imshow(item["image"])
        row[0].set_title(item["title"], fontsize=9)
        shown = row[1].imshow(item["tiles"], cmap="magma", vmin=lo, vmax=hi,
                              extent=(0, w, h, 0), interpolation="nearest")  # fmt: skip
        row[1].set_title("delentropy per tile", fontsize=9)
        row[2].imshow(shades[np.minimum(item["errors"], 2)], interpolation="nearest")
        wrong = item["errors"] == 1
        share = wrong.sum() / max(1, (item["errors"] != 2).sum())
        row[2].set_title(f"error pixels ({100 * share:.1f} % wrong)", fontsize=9)
        for ax in row:
            ax.set_axis_off()
    if shown is not None:
        fig.colorbar(shown, ax=axes[:, 1].tolist(), location="bottom", shrink=0.8,
                     label="tile delentropy (bits)")  # fmt: skip
    return save_figure(fig, path, dpi=80)


def plot_compare(
    reports: Sequence[dict[str, Any]],
    names: Sequence[str],
    path: str | Path,
    analysis: dict[str, Any] | None = None,
) -> Path:
    """Grouped bars: the mIoU of each bin (rows matched by position) for each report, with
    their intervals; with ``analysis`` (``compare.json``) a second panel draws each report's
    gap to the baseline per bin with its interval."""
    n_bins = max(len(r["bins"]) for r in reports)
    width = 0.8 / len(reports)
    panels = 2 if analysis is not None else 1
    fig = Figure(figsize=(max(6, 1.8 * n_bins + 2), 4.5 * panels), layout="constrained")
    axes = fig.subplots(panels, 1, squeeze=False)[:, 0]
    ax = axes[0]
    for k, (report, name) in enumerate(zip(reports, names, strict=True)):
        values = [np.nan if r["miou"] is None else r["miou"] for r in report["bins"]]
        xs = np.arange(len(values)) + (k - (len(reports) - 1) / 2) * width
        err = error_bars(values, report["bins"], "miou_ci")
        bars = ax.bar(xs, values, width, label=name, yerr=err, capsize=4)
        ax.bar_label(bars, labels=[_fmt(r["miou"]) for r in report["bins"]], fontsize=8)
    first = max(reports, key=lambda r: len(r["bins"]))
    ax.set_xticks(range(n_bins), [bin_label(r) for r in first["bins"]])
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("mIoU")
    ax.set_title("mIoU per complexity bin")
    ax.legend()
    if analysis is not None:
        _plot_gaps(axes[1], analysis, [bin_label(r) for r in first["bins"]])
    return save_figure(fig, path)


def _plot_gaps(ax: Any, analysis: dict[str, Any], labels: Sequence[str]) -> None:
    """Gap B − A per bin (points) with interval bars; 0 drawn as a line."""
    # A report keeps its colour of the top panel (C1 for the first after the baseline), also
    # when a report between is not comparable and draws no gap.
    comps = [(i, c) for i, c in enumerate(analysis["comparisons"])
             if c.get("comparable") is not False]  # fmt: skip
    width = 0.8 / max(1, len(comps))
    for k, (index, comp) in enumerate(comps):
        rows = comp["bins"]
        values = [np.nan if r["gap"] is None else 100 * r["gap"] for r in rows]
        scaled = [{"ci": None if not r.get("gap_ci") else [100 * v for v in r["gap_ci"]]}
                  for r in rows]  # fmt: skip
        xs = np.arange(len(rows)) + (k - (len(comps) - 1) / 2) * width
        err = error_bars(values, scaled, "ci")
        kind = "paired" if comp["paired"] else "unpaired"
        ax.bar(xs, values, width, yerr=err, capsize=4, color=f"C{index + 1}",
               label=f"{comp['report']} − {analysis['baseline']} ({kind})")  # fmt: skip
    ax.axhline(0, color="k", lw=1)
    ax.set_xticks(range(len(labels)), labels)
    level = analysis["uncertainty"]["level"]
    ax.set_ylabel("mIoU gap (points)")
    ax.set_title(f"gap to {analysis['baseline']} per bin, {level:.0%} intervals")
    if comps:  # none when no report is comparable to the baseline
        ax.legend()


def plot_metric_bins(report: dict[str, Any], metric: str, path: str | Path) -> Path:
    """A ``scores`` metric's mean per complexity bin, with interval bars."""
    rows = report["bins"]
    entries = [r["scores"][metric] for r in rows]
    values = [np.nan if e["mean"] is None else e["mean"] for e in entries]
    fig = Figure(figsize=(max(5, 1.6 * len(rows) + 2), 4), layout="constrained")
    ax = fig.subplots()
    bars = ax.bar(range(len(rows)), values, color="tab:green",
                  yerr=error_bars(values, entries, "ci"), capsize=6)  # fmt: skip
    ax.bar_label(bars, labels=[_fmt(e["mean"], 3) for e in entries], padding=2)
    ax.set_xticks(range(len(rows)), [bin_label(r) for r in rows])
    overall = report["overall"]["scores"][metric]["mean"]
    if overall is not None:
        ax.axhline(overall, color="k", ls="--", lw=1, label=f"overall {overall:.3f}")
        ax.legend(loc="best")
    ax.set_ylabel(f"mean {metric}")
    ax.set_xlabel("delentropy bin")
    ax.set_title(f"{metric} per complexity bin")
    return save_figure(fig, path)


def plot_metric_scatter(
    report: dict[str, Any], metric: str, path: str | Path, measure: str = "delent"
) -> Path:
    """A ``scores`` metric per image against ``measure``, with the least-squares line."""
    x = np.array([np.nan if r.get(measure) is None else r[measure] for r in report["images"]])
    y = np.array([np.nan if r.get(metric) is None else r[metric] for r in report["images"]])
    corr = report["correlation"].get(measure, {}).get(metric, {})
    fig = _scatter(x, y, corr, f"{metric} vs {measure}", f"{measure} (bits)", metric, "+.3g")
    return save_figure(fig, path)
