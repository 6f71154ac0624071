"""Tone: dot sizes that make a stipple's rendering match the map's L channel (paper §7),
and density-fidelity measures (SSIM, PSNR) between a rendering and the density.

Tone images are (H, W) arrays in [0, 1] with 1 = black ink, compared with the
density ``1 - L/100`` at the map's resolution.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates

from synthesis.labmap import LabMap
from synthesis.points import PointSet
from synthesis.render import tone_image

AREA_NEIGHBOURS = 6
REFINE_STEPS = 4


def blur_pixels(points: PointSet, width_px: int) -> float:
    """Gaussian blur (pixels) under which a stipple reads as tone: one mean point spacing."""
    w, h = points.domain
    return math.sqrt(w * h / len(points)) * width_px / w


def _sample(image: np.ndarray, xy: np.ndarray, width_px: int, w: float) -> np.ndarray:
    scale = width_px / w
    return map_coordinates(image, [xy[:, 1] * scale - 0.5, xy[:, 0] * scale - 0.5], order=1, mode="nearest")


def dot_sizes(points: PointSet, lab_map: LabMap, width_px: int = 512) -> PointSet:
    """The same points with radii so the blurred rendering matches the density.

    Start from ``r = sqrt(d(x) A / pi)`` with A the local area per point (from
    the distance to the 6th nearest neighbour), then rescale every radius a few
    times by ``sqrt(target tone / rendered tone)`` measured at the point.
    """
    w, h = points.domain
    density = lab_map.density()
    target = _sample(density, points.xy, density.shape[1], w)
    from scipy.spatial import cKDTree  # only for dot sizes: scipy.spatial takes 0.05 s to import

    distance, _ = cKDTree(points.xy).query(points.xy, k=AREA_NEIGHBOURS + 1)
    area = math.pi * distance[:, -1] ** 2 / AREA_NEIGHBOURS
    radius = np.sqrt(np.clip(target, 0, 1) * area / math.pi)
    blur = blur_pixels(points, width_px)
    wanted = _sample(gaussian_filter(_resample(density, width_px, w, h), blur, mode="nearest"), points.xy, width_px, w)
    for _ in range(REFINE_STEPS):
        rendered = _sample(tone_image(PointSet(points.xy, points.domain, radius), width_px, blur), points.xy, width_px, w)
        radius = radius * np.sqrt(np.clip(wanted, 1e-3, 1) / np.clip(rendered, 1e-3, 1)).clip(0.5, 2.0)
    return PointSet(points.xy, points.domain, radius, points.points_per_ink)


def _resample(image: np.ndarray, width_px: int, w: float, h: float) -> np.ndarray:
    """(H, W) image bilinearly resampled to the render raster of ``width_px``."""
    height_px = max(1, round(width_px * h / w))
    rows = (np.arange(height_px) + 0.5) * image.shape[0] / height_px - 0.5
    cols = (np.arange(width_px) + 0.5) * image.shape[1] / width_px - 0.5
    grid = np.meshgrid(rows, cols, indexing="ij")
    return map_coordinates(image, grid, order=1, mode="nearest")


def ssim(a: np.ndarray, b: np.ndarray, sigma: float = 1.5) -> float:
    """Mean structural similarity (Wang et al. 2004) of two images in [0, 1], Gaussian window."""
    c1, c2 = 0.01**2, 0.03**2
    mu_a, mu_b = gaussian_filter(a, sigma), gaussian_filter(b, sigma)
    var_a = gaussian_filter(a * a, sigma) - mu_a**2
    var_b = gaussian_filter(b * b, sigma) - mu_b**2
    cov = gaussian_filter(a * b, sigma) - mu_a * mu_b
    index = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return float(index.mean())


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of two images in [0, 1]."""
    mse = float(np.mean((a - b) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def density_fidelity(points: PointSet, lab_map: LabMap) -> dict[str, float]:
    """SSIM and PSNR between the blurred rendering of a stipple and the map's density.

    The rendering is made at the map's width and blurred by one mean point
    spacing; points without radii use the renderer's default dot size scaled
    so its mean tone equals the mean density (only the shape of the tone is
    compared, not the overall ink).
    """
    width_px = lab_map.width
    density = lab_map.density().astype(np.float64)
    tone = tone_image(points, width_px, blur_pixels(points, width_px)).astype(np.float64)
    tone = tone[: density.shape[0], : density.shape[1]]
    if points.radius is None:
        tone = tone * (density.mean() / max(tone.mean(), 1e-9))
    blurred = gaussian_filter(density, blur_pixels(points, width_px), mode="nearest")
    return {"ssim": round(ssim(np.clip(tone, 0, 1), blurred), 4), "psnr_db": round(psnr(np.clip(tone, 0, 1), blurred), 2)}
