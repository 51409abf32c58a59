"""Complexity where the error happens: an image cut into a grid of tiles, each measured alone.

Along an axis of length L, tiles of about T pixels: n = max(1, round(L / T)) tiles with
boundaries round(k·L/n), k = 0..n, so there is no remnant and every pixel is in exactly one tile.
Both roundings are to the nearest integer, halves to even (Python's ``round``), in exact
integer arithmetic. A tile's complexity is the per-image recipe (greyscale, 3×3 Gaussian σ = 1,
Sobel, 511-bin deldensity for ``delent``) applied to the tile's pixels as an image of its own:
its blur and gradients see the tile's own borders, not its neighbours.

A tile is at least :data:`MIN_TILE_SIZE` pixels: the 3×3 blur and the 3×3 Sobel after it reach
2 pixels past each border, so in a T×T tile 1 − ((T − 4) / T)² of the gradients see the border
padding (23 % at 32 px, 44 % at 16, 75 % at 8), and the 2-D gradient histogram of 511×511 bins
needs pixels to hold more than a handful of counts (1,024 at 32 px, 4 at 2 px, where every tile's
delentropy came out 0). An image is cut into at most :data:`MAX_TILES_PER_IMAGE` tiles (a 32×32
grid): each tile keeps a K×K confusion, 0.5 MB per image for the 8 UAVid classes at the bound,
where ``--tiles 2`` took 1.1 GB for four small images.
"""

from __future__ import annotations

import numpy as np

from claravid.dsp.metrics import check_blur_ksize, check_metric, gray_complexity, preprocess


def _round_div(a: int, b: int) -> int:
    """round(a / b) for integers a >= 0, b > 0, halves to even, without floating point."""
    q, r = divmod(a, b)
    if 2 * r > b or (2 * r == b and q % 2 == 1):
        q += 1
    return q


#: The smallest tile measured (pixels; module docstring).
MIN_TILE_SIZE: int = 32
#: The most tiles one image is cut into (module docstring).
MAX_TILES_PER_IMAGE: int = 1024


def check_tile_size(size: int) -> int:
    """Return ``size`` if it is a usable tile size (an integer >= :data:`MIN_TILE_SIZE`)."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < MIN_TILE_SIZE:
        raise ValueError(
            f"tile size must be an integer of at least {MIN_TILE_SIZE} pixels (a 3x3 blur and "
            f"Sobel need that many for a meaningful gradient histogram), got {size!r}"
        )
    return int(size)


def check_tile_count(shape: tuple[int, ...], size: int, name: str = "an image") -> int:
    """The number of tiles of an image of ``shape`` (H, W, ...); raise past the bound.

    Raises:
        ValueError: more than :data:`MAX_TILES_PER_IMAGE` tiles; the message gives the
            smallest tile size within the bound.
    """
    height, width = int(shape[0]), int(shape[1])
    rows, cols = (max(1, _round_div(n, size)) for n in (height, width))
    if rows * cols <= MAX_TILES_PER_IMAGE:
        return rows * cols
    smallest = size
    while max(1, _round_div(height, smallest)) * max(1, _round_div(width, smallest)) > (
        MAX_TILES_PER_IMAGE
    ):
        smallest += 1
    raise ValueError(
        f"tiles of {size} px cut {name} of {width}x{height} into {rows * cols} tiles, more than "
        f"{MAX_TILES_PER_IMAGE}: use tiles of {smallest} px or more"
    )


def tile_bounds(length: int, size: int) -> np.ndarray:
    """Tile boundaries along an axis of ``length`` pixels for tiles of about ``size`` pixels.

    Returns:
        int64 [n + 1]: 0 = b_0 < b_1 < ... < b_n = length; tile k covers [b_k, b_{k+1}).
    """
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 2:
        raise ValueError(f"tile size must be an integer of at least 2 pixels, got {size!r}")
    size = int(size)
    if length < 1:
        raise ValueError(f"cannot cut an axis of {length} pixels into tiles")
    n = max(1, _round_div(length, size))
    return np.array([_round_div(k * length, n) for k in range(n + 1)], dtype=np.int64)


def tile_grid(shape: tuple[int, ...], size: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column boundaries (:func:`tile_bounds`) of an image of ``shape`` (H, W, ...)."""
    return tile_bounds(int(shape[0]), size), tile_bounds(int(shape[1]), size)


def tile_complexities(
    gray: np.ndarray, size: int, metric: str = "delent", blur: bool = True, ksize: int = 3
) -> np.ndarray:
    """The complexity of every tile of a decoded 8-bit greyscale image (not yet blurred).

    Args:
        gray: 2-D uint8 array, as :func:`claravid.dsp.read_gray` returns it.
        size: the tile size T in pixels.
        metric: ``delent``, ``glcment`` or ``pixent``.
        blur: blur each tile before measuring (the official default).
        ksize: odd Gaussian kernel size.

    Returns:
        float64 [rows, cols], row-major as the tiles lie in the image.
    """
    check_metric(metric)
    size = check_tile_size(size)
    if blur:
        check_blur_ksize(ksize)
    check_tile_count(gray.shape, size)
    ys, xs = tile_grid(gray.shape, size)
    out = np.empty((len(ys) - 1, len(xs) - 1), dtype=np.float64)
    for r in range(len(ys) - 1):
        for c in range(len(xs) - 1):
            tile = gray[ys[r] : ys[r + 1], xs[c] : xs[c + 1]]
            out[r, c] = gray_complexity(preprocess(tile, blur, ksize), metric)
    return out
