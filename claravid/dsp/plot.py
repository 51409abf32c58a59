"""The profile plot: histogram of per-image values, fitted Beta density, and a mu line.

The official plot (seaborn histogram + dashed red Beta pdf + red mean line, legend alpha, beta,
mu, sigma), redrawn with matplotlib alone and without pyplot, so it works headless and in workers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from claravid.dsp.measures import METRIC_NAMES
from claravid.dsp.profile import Profile, fit_profile
from claravid.infra.files import atomic_save

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure, SubFigure


def plot_profile(
    values: Sequence[float] | np.ndarray,
    profile: Profile | None = None,
    path: str | Path | None = None,
    *,
    title: str | None = None,
    metric: str = "delent",
    dpi: int = 150,
    ax: Axes | None = None,
) -> Figure | SubFigure:
    """Draw (and save when ``path`` is given) a scene profile.

    Args:
        values: per-image complexities (non-finite values are left out).
        profile: the fitted profile; fitted from ``values`` when None.
        path: PNG (or any matplotlib format, from the suffix) to write atomically; parent
            folders are created.
        title: figure title; default "Scene complexity profile - <metric name>".
        metric: metric key, for the default title and the x label.
        dpi: resolution of the saved file.
        ax: a matplotlib Axes to draw into (e.g. one panel of a grid); default a new figure.

    Returns:
        The matplotlib Figure that holds the plot (a SubFigure when ``ax`` is in one).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    vals = np.asarray(values, dtype=np.float64).reshape(-1)
    vals = vals[np.isfinite(vals)]
    if profile is None:
        profile = fit_profile(vals)
    name = METRIC_NAMES.get(metric, metric)

    if ax is None:
        new = Figure(figsize=(7, 4.5), layout="constrained")
        FigureCanvasAgg(new)
        ax = new.add_subplot()
    fig = ax.figure
    if vals.size:
        bins = "auto" if vals.size > 1 and np.ptp(vals) > 0 else 10
        ax.hist(vals, bins=bins, density=True, color="#4c72b0", alpha=0.6, edgecolor="white")
    label = (
        f"α={profile.alpha:.2f}\nβ={profile.beta:.2f}\nμ={profile.mu:.2f}\nσ={profile.sigma:.2f}"
    )
    if math.isfinite(profile.alpha) and profile.b > profile.a:
        grid = np.linspace(profile.a, profile.b, 300)
        pdf = profile.pdf(grid)
        # A U-shaped Beta (alpha or beta < 1) is infinite at the ends; keep the histogram readable.
        if vals.size > 1:
            top = np.histogram(vals, bins="auto", density=True)[0].max() * 3
            pdf = np.minimum(pdf, top)
        ax.plot(grid, pdf, "r--", lw=2, label=f"Beta fit\n{label}")
    else:
        ax.plot([], [], "r--", label=f"no Beta fit\n{label}")
    if math.isfinite(profile.mu):
        ax.axvline(profile.mu, color="red", lw=1.5, label="μ")
    ax.set_xlabel(f"{name} (bits)")
    ax.set_ylabel("density")
    ax.grid(True, alpha=0.5, linestyle="--", color="silver")
    ax.spines[["top", "right"]].set_visible(False)
    ax.legend(loc="best", fontsize=9)
    ax.set_title(title or f"Scene complexity profile - {name} ({vals.size} images)")
    if path is not None:
        save_figure(fig.figure, path, dpi=dpi)  # the root figure: a SubFigure cannot be saved
    return fig


def plot_format(path: str | Path) -> str:
    """The matplotlib format of ``path`` from its suffix; ValueError when none is supported.

    Check it before long work: matplotlib only complains when saving.
    """
    from matplotlib.backend_bases import FigureCanvasBase

    suffix = Path(path).suffix.lower().lstrip(".")
    formats = FigureCanvasBase.get_supported_filetypes()
    if suffix not in formats:
        raise ValueError(
            f"cannot save a plot as {path}: give a file name ending in one of "
            f"{', '.join('.' + f for f in sorted(formats))} (e.g. profile.png)"
        )
    return suffix


def save_figure(fig: Figure, path: str | Path, dpi: int = 150) -> Path:
    """Save ``fig`` to ``path`` atomically, in the format its suffix names."""
    fmt = plot_format(path)
    return atomic_save(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=fmt))
