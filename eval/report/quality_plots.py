"""Pictures of the measures beyond mIoU, each written atomically.

- ``reliability.png``: the reliability diagram of every complexity bin and of the whole split:
  per confidence bin, the accuracy of its pixels against their mean confidence (the diagonal
  is perfect calibration), the share of pixels per confidence bin below, ECE in the title;
- ``consistency_per_bin.png``: cross-view consistency per complexity bin, the predictions'
  beside the ground truth's (the ceiling), with bootstrap intervals;

The pairs of lowest consistency are drawn in ``hardest.png``
(:func:`claravid.eval.report.plots.hardest_figure`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from claravid.eval.report.plots import bin_label, error_bars, save_figure

QUALITY_PLOTS = {"reliability": "reliability.png", "consistency": "consistency_per_bin.png"}


def plot_reliability(report: dict[str, Any], path: str | Path) -> Path:
    """One reliability diagram per complexity bin and one for the whole split."""
    rows = [*report["bins"], {"name": "overall", **report["overall"]}]
    fig = Figure(figsize=(3.2 * len(rows), 4.2), layout="constrained")
    axes = fig.subplots(2, len(rows), squeeze=False, height_ratios=[3, 1], sharex=True)
    for j, row in enumerate(rows):
        cal = row["calibration"]
        rel = cal["reliability"]
        b = len(rel["count"])
        edges = np.linspace(0.0, 1.0, b + 1)
        centres, width = (edges[:-1] + edges[1:]) / 2, 1.0 / b
        acc = np.array([np.nan if a is None else a for a in rel["accuracy"]])
        conf = np.array([np.nan if c is None else c for c in rel["confidence"]])
        top, bottom = axes[0, j], axes[1, j]
        top.bar(centres, np.nan_to_num(acc), width, color="tab:blue", edgecolor="k", lw=0.5,
                label="accuracy")  # fmt: skip
        top.bar(centres, np.nan_to_num(conf - acc), width, bottom=np.nan_to_num(acc),
                color="tab:red", alpha=0.35, label="gap to confidence")  # fmt: skip
        top.plot([0, 1], [0, 1], "k--", lw=1)
        top.set_xlim(0, 1)
        top.set_ylim(0, 1)
        ece = "–" if cal["ece"] is None else f"{cal['ece']:.3f}"
        title = "overall" if row["name"] == "overall" else bin_label(row).replace("\n", " ")
        top.set_title(f"{title}\nECE {ece}", fontsize=9)
        share = np.asarray(rel["count"], np.float64) / max(1, cal["num_pixels"])
        bottom.bar(centres, share, width, color="grey")
        bottom.set_xlabel("confidence")
        if j == 0:
            top.set_ylabel("accuracy")
            bottom.set_ylabel("share of pixels")
            top.legend(loc="upper left", fontsize=8)
    fig.suptitle("Reliability per complexity bin")
    return save_figure(fig, path)


def plot_consistency(report: dict[str, Any], path: str | Path) -> Path:
    """Consistency per bin: predictions beside the ground truth (the ceiling), with intervals."""
    rows = report["bins"]
    entries = [r["consistency"] for r in rows]
    fig = Figure(figsize=(max(5, 1.8 * len(rows) + 2), 4), layout="constrained")
    ax = fig.subplots()
    xs = np.arange(len(rows))
    for offset, key, label, color in ((-0.2, "agreement", "prediction", "tab:blue"),
                                      (0.2, "agreement_gt", "ground truth (ceiling)",
                                       "tab:grey")):  # fmt: skip
        values = [np.nan if e[key] is None else e[key] for e in entries]
        scaled = [{"ci": e.get(f"{key}_ci")} for e in entries]
        bars = ax.bar(xs + offset, values, 0.4, label=label, color=color,
                      yerr=error_bars(values, scaled, "ci"), capsize=5)  # fmt: skip
        ax.bar_label(bars, labels=["–" if e[key] is None else f"{e[key]:.3f}" for e in entries],
                     fontsize=8, padding=2)  # fmt: skip
    labels = [f"{bin_label(r)}\npairs={e['pairs']['ok']}" for r, e in zip(rows, entries,
                                                                          strict=True)]  # fmt: skip
    ax.set_xticks(xs, labels)
    ax.set_ylim(0, 1.08)
    ax.set_ylabel("kept pixels that agree")
    ax.set_xlabel("delentropy bin (of frame t)")
    ax.set_title("Cross-view consistency per complexity bin")
    ax.legend(loc="lower left")
    return save_figure(fig, path)
