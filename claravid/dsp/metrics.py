"""Per-image complexity: delentropy and the paper's two baselines, with the official values.

The official ClaraVid code (``claravid/scene_complexity_profile.py``) builds the deldensity with
``np.histogram2d`` on int64 copies of the Sobel gradients: 1-3 s and about 1.1 GB per 12 MP image.
Here the same 511 x 511 histogram is counted exactly, in integers, from the int16 gradients:

* An int16 gradient ``g`` in [-128, 127] is identified by its low byte alone, so one 8-bit 2-D
  ``cv2.calcHist`` over the low bytes of (gx, gy) (a zero-copy view), masked to the pixels whose two
  gradients both lie in that core range, counts them; OpenCV's 8-bit histogram is a table look-up,
  not a search.
* The few pixels outside the core ("tail", a few percent of a photo) are gathered and counted with
  a look-up table from gradient to bin.
* With the optional C module ``_deldensity`` (built at install when a compiler is there), one
  pass over (gx, gy) through the same look-up table counts everything instead, twice as fast.
* The look-up table is built from numpy's own bin edges with numpy's own rule (``searchsorted``,
  last edge closed), so every integer in [-256, 256] lands in the bin ``np.histogram2d`` gives it,
  and gradients outside that range are dropped, as there.
"""

from __future__ import annotations

import threading
from pathlib import Path

import cv2
import numpy as np

from claravid.dsp.measures import METRICS
from claravid.infra.errors import CorruptFileError
from claravid.io.modalities import decode_bytes, read_checked

_NUM_BINS = 511  # official: 512 - 1 bins per axis over [-256, 256]
_RANGE = 256.0
_GMAX = 4 * 255  # |3x3 Sobel| of an 8-bit image never exceeds 1020
_DROP = _NUM_BINS  # an extra bin collecting out-of-range gradients, cut off at the end
# OpenCV returns histogram counts as float32: exact only below 2**24, so count in row blocks.
_MAX_BLOCK_PIXELS = (1 << 24) - 1


def _build_bin_lut() -> np.ndarray:
    """Bin of every integer gradient in [-1020, 1020], exactly as ``np.histogram2d`` assigns it."""
    edges = np.linspace(-_RANGE, _RANGE, _NUM_BINS + 1)  # the edges histogram2d builds
    grads = np.arange(-_GMAX, _GMAX + 1)
    bins = np.searchsorted(edges, grads, side="right") - 1
    bins[grads == edges[-1]] = _NUM_BINS - 1  # numpy closes the last bin
    bins[(grads < edges[0]) | (grads > edges[-1])] = _DROP
    return bins.astype(np.intp)


#: gradient + 1020 -> bin index in [0, 511); 511 = dropped.
BIN_LUT: np.ndarray = _build_bin_lut()
BIN_LUT.setflags(write=False)
_BIN_LUT32 = BIN_LUT.astype(np.int32)  # int32 indices: half the memory traffic of intp
# The C module's table: the bin of every int16 value, indexed by its uint16 bit pattern.
_BIN_LUT_U16 = np.full(1 << 16, _DROP, np.uint16)
_BIN_LUT_U16[np.arange(-_GMAX, _GMAX + 1).astype(np.uint16)] = BIN_LUT

try:  # the optional C histogram (built at install when a compiler is there): 2x faster
    from claravid.dsp import _deldensity as _native
except ImportError:  # pragma: no cover - depends on the build
    _native = None  # type: ignore[assignment]  # mypy types a module name as never None
# Bin of each low byte for core gradients in [-128, 127] (byte b <-> gradient b or b - 256).
_LOW_BYTE = np.arange(256)
_CORE_BIN = BIN_LUT[np.where(_LOW_BYTE < 128, _LOW_BYTE, _LOW_BYTE - 256) + _GMAX]


def _check_gray(gray: np.ndarray) -> np.ndarray:
    gray = np.asarray(gray)
    if gray.ndim != 2:
        raise ValueError(
            f"expected a 2-D greyscale image, got shape {gray.shape}; "
            "convert colour images with cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) first"
        )
    if gray.dtype != np.uint8:
        raise ValueError(
            f"expected an 8-bit image (uint8), got {gray.dtype}; the official metrics are "
            "defined on 8-bit greyscale, e.g. as read by cv2.imread(path, cv2.IMREAD_GRAYSCALE)"
        )
    if gray.size == 0:
        raise ValueError("the image is empty (0 pixels)")
    return np.ascontiguousarray(gray)


def _hist2d_u8(
    first: np.ndarray,
    second: np.ndarray,
    channels: tuple[int, int] = (0, 1),
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Exact int64 256 x 256 histogram of two 8-bit images (or byte views), row block by block.

    Only pixels where ``mask`` (uint8, same rows and columns) is non-zero count, when given.
    """
    rows, cols = first.shape[:2]
    step = max(1, _MAX_BLOCK_PIXELS // max(cols, 1))
    total = np.zeros((256, 256), np.int64)
    for r in range(0, rows, step):
        block = cv2.calcHist(
            [first[r : r + step], second[r : r + step]],
            list(channels),
            None if mask is None else mask[r : r + step],
            [256, 256],
            [0, 256, 0, 256],
        )
        total += block.astype(np.int64)
    return total


def _entropy_bits(counts: np.ndarray) -> float:
    """-sum p log2 p over the non-zero counts, p = counts / total, summed in float64."""
    nonzero = counts[counts > 0].astype(np.float64)
    if nonzero.size == 0:
        return 0.0
    p = nonzero / nonzero.sum()
    return float(-np.sum(p * np.log2(p)))


def deldensity_counts(gray: np.ndarray) -> np.ndarray:
    """The 511 x 511 deldensity of an 8-bit image, as integer counts indexed ``[gx_bin, gy_bin]``.

    Equal, bin for bin, to ``np.histogram2d(gx, gy, bins=511, range=[[-256, 256]] * 2)[0]`` where
    gx, gy are ``cv2.Sobel`` (ksize 3, int16, default border) of the image.
    """
    gray = _check_gray(gray)
    # Same values as cv2.Sobel on int16 (ksize 3, reflect-101 border), both in one pass.
    gx, gy = cv2.spatialGradient(gray, ksize=3)
    if _native is not None:
        counts = np.zeros((_NUM_BINS + 1, _NUM_BINS + 1), np.uint32)
        _native.count(gx, gy, _BIN_LUT_U16, counts)  # exact: < 2**32 pixels per call
        return counts[:_NUM_BINS, :_NUM_BINS].astype(np.int64)
    return _counts_opencv(gx, gy)


def _counts_opencv(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """The deldensity counts without the C module: OpenCV 8-bit histograms plus numpy."""
    rows, cols = gx.shape
    low_x = gx.view(np.uint8).reshape(rows, cols, 2)  # channel 0 = low byte (little-endian)
    low_y = gy.view(np.uint8).reshape(rows, cols, 2)
    core = cv2.inRange(gx, -128, 127)
    cv2.bitwise_and(core, cv2.inRange(gy, -128, 127), dst=core)

    # The core histogram (masked to core pixels, so no aliasing) runs in a thread (OpenCV
    # releases the GIL) while this thread counts the tail.
    result: dict[str, np.ndarray] = {}

    def count_core() -> None:
        result["core"] = _hist2d_u8(low_x, low_y, channels=(0, 2), mask=core)

    worker = threading.Thread(target=count_core, daemon=True)
    worker.start()
    tail = np.flatnonzero(core.reshape(-1) == 0)
    index = _BIN_LUT32[gx.reshape(-1)[tail] + _GMAX]
    index *= _NUM_BINS + 1
    index += _BIN_LUT32[gy.reshape(-1)[tail] + _GMAX]
    del tail
    counts = np.bincount(index, minlength=(_NUM_BINS + 1) ** 2).reshape(
        _NUM_BINS + 1, _NUM_BINS + 1
    )
    worker.join()
    # Core gradients map one-to-one onto bins, so a fancy-indexed add never collides.
    counts[_CORE_BIN[:, None], _CORE_BIN[None, :]] += result["core"]
    return counts[:_NUM_BINS, :_NUM_BINS]


def delentropy(gray: np.ndarray) -> float:
    """Delentropy of an 8-bit greyscale image (already blurred if blurring is wanted).

    int16 Sobel (3x3), 511 x 511 deldensity over [-256, 256] with ``np.histogram2d`` bin rules
    (last bin closed, out-of-range gradients dropped), then ``-1/2 * sum p log2 p``. Equal to the
    official ``compute_delentropy`` to rounding (~1e-15).

    Args:
        gray: 2-D uint8 array.

    Returns:
        Delentropy in bits.
    """
    return 0.5 * _entropy_bits(deldensity_counts(gray))


def glcm_entropy(gray: np.ndarray) -> float:
    """GLCM entropy in bits: distance 1, angle 0, 256 levels, symmetric, normalised.

    The co-occurrence matrix counts horizontal neighbour pairs ``(I[r, c], I[r, c + 1])`` and adds
    its transpose, as scikit-image's ``graycomatrix(..., symmetric=True, normed=True)``; an image
    one pixel wide has no pairs and entropy 0, as in the official code.

    Args:
        gray: 2-D uint8 array.

    Returns:
        Entropy of the normalised GLCM in bits.
    """
    gray = _check_gray(gray)
    if gray.shape[1] < 2:
        return 0.0
    pairs = _hist2d_u8(gray[:, :-1], gray[:, 1:])
    return _entropy_bits(pairs + pairs.T)


def pixel_entropy(gray: np.ndarray) -> float:
    """Shannon entropy in bits of the 256-bin intensity histogram over [0, 256).

    Args:
        gray: 2-D uint8 array.

    Returns:
        Entropy in bits.
    """
    gray = _check_gray(gray)
    counts = np.zeros(256, np.int64)
    step = max(1, _MAX_BLOCK_PIXELS // gray.shape[1])
    for r in range(0, gray.shape[0], step):
        block = cv2.calcHist([gray[r : r + step]], [0], None, [256], [0, 256])
        counts += block.reshape(-1).astype(np.int64)
    return _entropy_bits(counts)


_FUNCTIONS = {"delent": delentropy, "glcment": glcm_entropy, "pixent": pixel_entropy}


class ImageReadError(CorruptFileError):
    """An image file is missing, empty, truncated or not decodable; the message says which.

    A ``CorruptFileError``, so one ``except CorruptFileError`` catches every unreadable file of
    the toolkit. Kept as its own name because it also covers files that are missing or not
    regular files, which the DSP collection reports per image (and lists under ``errors``)
    rather than raising, and because its message gives no re-copy advice for a missing file.
    """

    advice = ""  # a missing file needs no re-copy advice; the reason says what is wrong


def check_metric(metric: str) -> str:
    """Return ``metric`` if it is one of the official names, else raise a ValueError naming them."""
    if metric not in _FUNCTIONS:
        raise ValueError(f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")
    return metric


def check_blur_ksize(ksize: int) -> int:
    """Return ``ksize`` if it is a valid Gaussian kernel size (odd, >= 1), else raise ValueError."""
    if isinstance(ksize, bool) or not isinstance(ksize, (int, np.integer)):
        raise ValueError(f"blur kernel size must be an odd integer, got {ksize!r}")
    if ksize < 1 or ksize % 2 == 0:
        raise ValueError(f"blur kernel size must be odd and >= 1 (e.g. 3), got {ksize}")
    return int(ksize)


def read_gray(path: str | Path) -> np.ndarray:
    """Decode an image as 8-bit greyscale exactly as ``cv2.imread(path, cv2.IMREAD_GRAYSCALE)``.

    Raises:
        ImageReadError: the file is missing, empty, truncated, or not a decodable image.
    """
    return read_gray_views(path, stored=False)[0]


#: An EXIF block (JPEG APP1, PNG eXIf chunk) can carry an orientation tag; files without one
#: decode the same either way.
_EXIF_MARKERS = (b"Exif\x00\x00", b"eXIf")


def read_gray_views(path: str | Path, stored: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """The greyscale image as the official code reads it (``cv2.imread``: the EXIF orientation
    applied) and, with ``stored``, as the datasets and their labels read it (pixels as stored,
    as PIL reads them). One decode unless the file has an EXIF block; then the two can differ.

    Raises:
        ImageReadError: the file is missing, empty, truncated, or not a decodable image.
    """
    path = Path(path)
    if not path.exists():
        raise ImageReadError(path, "no such file")
    if not path.is_file():
        raise ImageReadError(path, "not a regular file")
    try:
        data = read_checked(path)
        official = decode_bytes(data, path, cv2.IMREAD_GRAYSCALE, exif_orientation=True)
        if not stored:
            return official, None
        head = data[: 1 << 16].tobytes()
        if not any(marker in head for marker in _EXIF_MARKERS):
            return official, official
        return official, decode_bytes(data, path, cv2.IMREAD_GRAYSCALE, exif_orientation=False)
    except CorruptFileError as exc:
        raise ImageReadError(path, exc.reason) from None
    except OSError as exc:
        raise ImageReadError(path, exc.strerror or str(exc)) from None


def preprocess(gray: np.ndarray, blur: bool = True, ksize: int = 3) -> np.ndarray:
    """Official pre-processing: Gaussian blur ksize x ksize, sigma 1, default border (or none)."""
    if not blur:
        return gray
    ksize = check_blur_ksize(ksize)
    return cv2.GaussianBlur(gray, (ksize, ksize), 1.0)


def gray_complexity(gray: np.ndarray, metric: str = "delent") -> float:
    """Apply the metric named ``metric`` (``delent``, ``glcment``, ``pixent``) to a uint8 image.

    An image of one grey level has entropy 0, never −0.0 (``−Σ p log p`` of p = 1).
    """
    return float(_FUNCTIONS[check_metric(metric)](gray)) + 0.0


def image_complexity(
    path: str | Path, metric: str = "delent", blur: bool = True, ksize: int = 3
) -> float:
    """Complexity of one image file, as the official ``ComplexityProfile.process_image``.

    Decodes greyscale (``cv2.IMREAD_GRAYSCALE``), blurs with a ksize x ksize Gaussian of sigma 1
    when ``blur`` is on, then applies the metric.

    Args:
        path: image file (any format OpenCV reads).
        metric: ``delent`` (delentropy), ``glcment`` (GLCM entropy) or ``pixent`` (pixel entropy).
        blur: blur before measuring (the official default).
        ksize: odd Gaussian kernel size.

    Returns:
        The complexity in bits.

    Raises:
        ImageReadError: the file cannot be read or decoded.
        ValueError: unknown metric or invalid kernel size.
    """
    check_metric(metric)
    if blur:
        check_blur_ksize(ksize)
    return gray_complexity(preprocess(read_gray(path), blur, ksize), metric)
