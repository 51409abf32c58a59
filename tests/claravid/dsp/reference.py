"""The official ClaraVid formulation of the three metrics, written from its documented semantics.

Slow by design (np.histogram2d on int64 gradients, as ``claravid/scene_complexity_profile.py``):
the reference our fast kernels must equal.
"""

from __future__ import annotations

import cv2
import numpy as np


def official_deldensity(img: np.ndarray) -> np.ndarray:
    fx = cv2.Sobel(img.astype(np.int16), ddepth=-1, dx=1, dy=0, ksize=3).astype(int)
    fy = cv2.Sobel(img.astype(np.int16), ddepth=-1, dx=0, dy=1, ksize=3).astype(int)
    hist, _, _ = np.histogram2d(
        x=fx.flatten(), y=fy.flatten(), bins=511, range=[[-256.0, 256.0], [-256.0, 256.0]]
    )
    return hist


def official_delentropy(img: np.ndarray) -> float:
    density = official_deldensity(img)
    density = (density / np.sum(density)).T
    nonzero = density > 0
    return float(-0.5 * np.sum(density[nonzero] * np.log2(density[nonzero])))


def official_glcm_entropy(img: np.ndarray) -> float:
    # scikit-image graycomatrix(distances=[1], angles=[0], levels=256, symmetric, normed)
    glcm = np.zeros((256, 256), np.uint32)
    np.add.at(glcm, (img[:, :-1].ravel(), img[:, 1:].ravel()), 1)
    p = (glcm + glcm.T).astype(np.float64)
    total = p.sum()
    p /= total if total else 1.0
    total = p.sum()
    p /= total if total else 1.0
    logs = -np.log2(p, where=p != 0, out=np.zeros_like(p))
    return float(np.sum(p * logs))


def official_pixel_entropy(img: np.ndarray) -> float:
    hist, _ = np.histogram(img.flatten(), bins=256, range=(0, 256))
    p = hist.astype(float) / hist.sum()
    p = p[p > 0]
    return float(-np.sum(p * np.log2(p)))


OFFICIAL = {
    "delent": official_delentropy,
    "glcment": official_glcm_entropy,
    "pixent": official_pixel_entropy,
}


def official_image_complexity(path, metric="delent", blur=True, ksize=3) -> float:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if blur:
        img = cv2.GaussianBlur(img, (ksize, ksize), 1.0)
    return OFFICIAL[metric](img)


def textured(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A photo-like 8-bit image: smooth shading, fine noise and a few hard-edged rectangles."""
    coarse = rng.standard_normal((height // 8 + 2, width // 8 + 2)).astype(np.float32)
    img = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC) * 40 + 128
    img += rng.normal(0, 8, (height, width)).astype(np.float32)
    for _ in range(4):
        y, x = rng.integers(0, height), rng.integers(0, width)
        img[y : y + height // 4, x : x + width // 4] = rng.integers(0, 256)
    return np.clip(img, 0, 255).astype(np.uint8)
