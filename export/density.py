"""What the points themselves say about L: sharpened where the pattern is regular, smoothed where its detail is noise.

The network reads density at a fixed bandwidth of a few point spacings, so a
fine-detailed stippling comes out softer than a kernel density estimate at one
pixel (on Floyd-Steinberg and Lloyd stipplings a KDE at 1-1.5 px beats the
network alone), while a smooth picture's random stippling comes out grainy (a
KDE at 8-16 px beats it there). How fine a count can be trusted depends on the pattern's
correlation and on how many points there are: the counts of a regular
(blue-noise, Lloyd, dithered) pattern vary far less than Poisson's, so a KDE
about one point spacing wide is nearly noise-free there, while a Poisson
pattern's is mostly noise.

:func:`sharpen_density` takes the fine counts where they can be trusted, per pixel:

1. **A two-guide filter** (:func:`two_guide_filter`; the guided filter of He,
   Sun and Tang 2013, with two guides): a kernel density estimate of the
   points whose kernel is :data:`SHARP_BANDWIDTH` local spacings wide
   (:func:`spacing_kde`: 1 px at full ink at 50,000 points per ink on 256 px,
   wider in light areas, so that a light area's points do not show as dots) is
   regressed, in Gaussian windows of :data:`GUIDE_RADIUS` full-ink spacings, on
   the network's density and on itself. The self-guide is regularised by the
   estimate's noise variance if the points were Poisson (``d / (4 pi h^2 f)``
   at density ``d``, kernel width ``h``, ``f`` points per map pixel at full
   ink), so a window keeps the estimate's own detail only where it varies more
   than Poisson noise would make it, and follows the network elsewhere.
2. **A regularity weight** (:func:`regularity_weight`) from the local
   Clark-Evans ratio (:func:`clark_evans_ratio`; Clark and Evans 1954): the
   mean distance from each point to its nearest neighbour over the mean
   distance a Poisson pattern of the same density would give (``1 / (2
   sqrt(lambda))``), averaged around each pixel. It is 1.0 for Poisson
   patterns, 1.26 for a jittered grid, 1.7 for Poisson-disk and Lloyd, 0.56
   for Thomas clusters (stationary patterns of ``patternshop_nn.ood``, 2,500 to
   50,000 points; measured, not fitted to the evaluation's pictures). The
   weight rises from 0 at :data:`POISSON_RATIO` to 1 at :data:`REGULAR_RATIO`:
   the filtered KDE where the points are regular, the network's density where
   they are Poisson or clustered (a cluster is not a dark spot: clustering
   must not read as density).

:func:`denoise_density` smooths what cannot be trusted. It needs a sample of
the noise the density carries; :func:`export.runtime.bootstrap_noise` makes one
by reading two Poisson resamplings of the map (:func:`poisson_resample`, a
parametric bootstrap: on stationary Poisson patterns at density 0.2 and 0.5
the network's own detail has 0.88-1.05 of that sample's energy at 1-16 px,
``bench/bench_denoise.py``). Level by level (Gaussians of
1, 2, 4 ... px, :func:`export.uncertainty.smoothing_levels`), a pixel takes the next smoothing
while the detail it removes is within ``1 +`` :data:`NOISE_TOLERANCE` of the
energy the same smoothing removes from the noise sample, in windows of
twice the level (at least 8 px; :class:`export.infer_config.InferConfig`): a flat area is smoothed wide, an edge or
a texture the noise cannot explain keeps its detail. ``infer``
(:func:`export.runtime.refine_density`) denoises the network's density with
the Poisson sample, sharpens it, and denoises the sharpened part again with
:data:`REGULAR_NOISE_SHARE` of the sample's energy: the median ratio of the
sharpened L's detail energy on stationary Poisson-disk and Lloyd patterns
(density 0.2 and 0.5, 1-16 px) to the Poisson sample's (0.32; range 0.08-0.98).

The result is water-filled back to the pattern's ink
(:func:`export.evidence.calibrate_density`) by the caller. The kernel width,
the guide window and the denoising's window and tolerance were chosen among a
few values on the evaluation's stipplings (``patternshop_nn.ood``: ``camera``,
``astronaut``, ``moon``, ``coins``); the unseen pictures of the model card are
the check that was not looked at first.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from export.infer_config import DEFAULT_INFER, InferConfig
from export.uncertainty import smoothing_ladder, smoothing_window
from synthesis.conventions import full_ink_points
from synthesis.points import PointSet
from synthesis.raster import point_raster

# Lengths in full-ink spacings, 1 / sqrt(points per map pixel at full ink): 1.15 px on a 256-px map at 50,000
# points per ink, 2.9 px at the default model's training scale (8,000), so the sharpening does the same to the
# same pattern at any scale or map width.
SHARP_BANDWIDTH = 0.9  # Gaussian KDE of the points, in local spacings (1.0 px at full ink, 50,000 per ink, 256 px)
BANDWIDTH_STEP = 2.0 ** 0.25  # the kernels' widths come in this ratio (each point takes the nearest)
MIN_DENSITY = 1.0 / 256  # a point's kernel is never wider than at this density (16 full-ink spacings)
GUIDE_RADIUS = 1.75  # Gaussian windows of the two-guide filter (2.0 px there)
REGULARITY_SIGMA = 3.5  # Gaussian window the Clark-Evans ratio is averaged over (4.0 px there)
NETWORK_RIDGE = 1e-3  # regularisation of the network guide (density^2): its variance is trusted above this
POISSON_RATIO = 1.15  # Clark-Evans ratio up to which the network's density is kept (Poisson: 1.0, +- 0.08 in a window)
REGULAR_RATIO = 1.65  # ratio from which the filtered KDE is taken whole (Poisson-disk and Lloyd: 1.7)
MAX_POINT_RATIO = 3.0  # a single point's ratio is capped here (a point the network put in a near-white pixel)

# Denoising (:func:`denoise_density`): the ladder of levels, its windows and softness are InferConfig's
# (export.uncertainty.smoothing_ladder, shared with the smoothing by a predicted uncertainty).
NOISE_TOLERANCE = 0.75  # a level is taken where the detail it removes has at most 1 + this times the noise's energy
RESAMPLE_SMOOTHING_PX = 2.0  # the intensity a Poisson resampling draws from (:func:`poisson_resample`)
REGULAR_NOISE_SHARE = 0.3  # a regular pattern's sharpened L, noise energy over the Poisson resampling's (measured)


def map_points(points: PointSet, shape: tuple[int, int]) -> np.ndarray:
    """(n, 2) the points in map pixel coordinates (x right, y down; a pixel's centre at +0.5) of a map (H, W)."""
    return np.asarray(points.xy, np.float64).reshape(-1, 2) * (shape[1] / points.domain[0])


def count_raster(xy_px: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) points per pixel, splatted bilinearly (sums kept), of points (n, 2) in map pixel coordinates."""
    side = max(shape)
    return point_raster(np.asarray(xy_px, np.float64) / side, side, clip=False)[:shape[0], :shape[1]].astype(np.float64)


def point_pixels(xy_px: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(rows (n,), columns (n,)) of the pixels of a map (H, W) holding points (n, 2) in map pixel coordinates."""
    return (np.clip(xy_px[:, 1].astype(np.int64), 0, shape[0] - 1),
            np.clip(xy_px[:, 0].astype(np.int64), 0, shape[1] - 1))


def point_density(xy_px: np.ndarray, density: np.ndarray) -> np.ndarray:
    """(n,) the map's density (H, W) at the pixel of each point (n, 2) in map pixel coordinates."""
    return density[point_pixels(xy_px, density.shape)]


def spacing_kde(xy_px: np.ndarray, density: np.ndarray, full_ink_per_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(density estimate (H, W), kernel width (H, W) in px) of points (n, 2) in map pixel coordinates.

    A sample-point KDE whose kernel follows the local spacing: each point's Gaussian is :data:`SHARP_BANDWIDTH`
    spacings ``1 / sqrt(d f)`` wide, ``d`` the map's ``density`` (H, W) in [0, 1] at the point (at least
    :data:`MIN_DENSITY`), ``f`` the points per pixel at full ink, rounded to a width of the geometric series
    of ratio :data:`BANDWIDTH_STEP` (one blur per width used). The kernel width map is the same rule per pixel.
    """
    full_ink_width = SHARP_BANDWIDTH / np.sqrt(full_ink_per_px)
    width = full_ink_width / np.sqrt(np.maximum(density, MIN_DENSITY))
    point_steps = np.rint(np.log(1.0 / np.sqrt(np.maximum(point_density(xy_px, density), MIN_DENSITY)))
                          / np.log(BANDWIDTH_STEP)).astype(np.int64)
    estimate = np.zeros(density.shape)
    for step in np.unique(point_steps):
        chosen = xy_px[point_steps == step]
        estimate += gaussian_filter(count_raster(chosen, density.shape), full_ink_width * BANDWIDTH_STEP ** step)
    return estimate / full_ink_per_px, width


def clark_evans_ratio(xy_px: np.ndarray, density: np.ndarray, full_ink_per_px: float, sigma_px: float) -> np.ndarray:
    """(H, W) the Clark-Evans ratio around each pixel of a map of ``density`` (H, W) in [0, 1].

    Each point's nearest-neighbour distance over Poisson's mean ``1 / (2 sqrt(lambda))``, with ``lambda =
    density x full_ink_per_px`` points per pixel at the point, capped at :data:`MAX_POINT_RATIO`; averaged
    with Gaussian weights of ``sigma_px``. 0 where no point is near, and everywhere below 2 points.
    """
    shape = density.shape
    ratio, support = np.zeros(shape), np.zeros(shape)
    if len(xy_px) < 2:
        return ratio
    from scipy.spatial import cKDTree  # here: importing scipy.spatial costs infer's start-up 0.1-0.3 s

    nearest = cKDTree(xy_px).query(xy_px, k=2)[0][:, 1]
    pixels = point_pixels(xy_px, shape)
    points_per_px = np.maximum(density[pixels], 1.0 / density.size) * full_ink_per_px
    np.add.at(ratio, pixels, np.minimum(nearest * 2.0 * np.sqrt(points_per_px), MAX_POINT_RATIO))
    np.add.at(support, pixels, 1.0)
    ratio, support = gaussian_filter(ratio, sigma_px), gaussian_filter(support, sigma_px)
    return np.divide(ratio, support, out=np.zeros(shape), where=support > 1e-9)


def regularity_weight(ratio: np.ndarray) -> np.ndarray:
    """(H, W) in [0, 1]: 0 up to a Clark-Evans ratio of :data:`POISSON_RATIO`, 1 from :data:`REGULAR_RATIO`, linear between."""
    return np.clip((np.asarray(ratio) - POISSON_RATIO) / (REGULAR_RATIO - POISSON_RATIO), 0.0, 1.0)


def two_guide_filter(source: np.ndarray, guide: np.ndarray, noise_per_mean: np.ndarray,
                     radius_px: float, guide_ridge: float = NETWORK_RIDGE) -> np.ndarray:
    """(H, W) ``source`` (H, W) filtered with two guides, ``guide`` (H, W) and ``source`` itself.

    In each Gaussian window of ``radius_px`` the output is ``a_g guide + a_s source + b``, least squares on
    ``source`` with ridges ``guide_ridge`` on ``a_g`` and the source's noise variance on ``a_s``, taken as
    Poisson-like: ``noise_per_mean`` (H, W) times the window's mean of the source (at least 0). The
    coefficients are averaged over the windows covering a pixel (He et al. 2013). A window where the source
    is flat and noise-free keeps its mean.
    """
    def mean(x: np.ndarray) -> np.ndarray:
        return gaussian_filter(x, radius_px)

    mean_g, mean_s = mean(guide), mean(source)
    var_g = mean(guide * guide) - mean_g * mean_g + guide_ridge
    var_s = mean(source * source) - mean_s * mean_s
    cov = mean(guide * source) - mean_g * mean_s
    regularised_s = var_s + noise_per_mean * np.maximum(mean_s, 0.0)
    det = var_g * regularised_s - cov * cov
    solvable = det > 1e-12 * var_g  # 0 only where the source is flat and noise-free: its mean is then exact
    a_g = np.divide(regularised_s * cov - cov * var_s, det, out=np.zeros_like(det), where=solvable)
    a_s = np.divide(var_g * var_s - cov * cov, det, out=np.zeros_like(det), where=solvable)
    b = mean_s - a_g * mean_g - a_s * mean_s
    return mean(a_g) * guide + mean(a_s) * source + mean(b)


def sharpen_density(points: PointSet, density: np.ndarray, points_per_ink: float) -> tuple[np.ndarray, np.ndarray]:
    """(density (H, W) in [0, 1], the weight (H, W) in [0, 1] of the part taken from the points) of a map whose
    network density is ``density`` (H, W) in [0, 1], already holding the pattern's ink at ``points_per_ink``
    (per unit area of full ink). Fewer than 2 points: the density unchanged, weight 0."""
    density = np.asarray(density, np.float64)
    if len(points) < 2:
        return density, np.zeros(density.shape)
    full_ink_per_px = full_ink_points(points_per_ink, points.domain) / density.size
    spacing_px = 1.0 / np.sqrt(full_ink_per_px)
    radius_px = GUIDE_RADIUS * spacing_px
    xy_px = map_points(points, density.shape)
    kde, width_px = spacing_kde(xy_px, density, full_ink_per_px)
    poisson_noise_per_mean = 1.0 / (4 * np.pi * width_px ** 2 * full_ink_per_px)  # a Poisson KDE's variance / its mean
    filtered = np.clip(two_guide_filter(kde, density, poisson_noise_per_mean, radius_px), 0.0, 1.0)
    weight = regularity_weight(clark_evans_ratio(xy_px, density, full_ink_per_px, REGULARITY_SIGMA * spacing_px))
    return weight * filtered + (1.0 - weight) * density, weight


def denoise_density(density: np.ndarray, noise: np.ndarray, noise_scale: float | np.ndarray = 1.0,
                    config: InferConfig = DEFAULT_INFER) -> tuple[np.ndarray, np.ndarray]:
    """(density (H, W), smoothing width (H, W) in px): ``density`` (H, W) smoothed where its detail is noise.

    ``noise`` (H, W) is a sample of the noise the density carries (:func:`export.runtime.bootstrap_noise`),
    ``noise_scale`` (scalar or (H, W), >= 0) the share of its energy to expect (0: none, nothing is smoothed
    but flat areas). Level by level (:func:`export.uncertainty.smoothing_ladder`), a pixel takes the next Gaussian
    smoothing while the detail that smoothing removes, ``density - blur(density)``, has at most ``1 +``
    :data:`NOISE_TOLERANCE` times the energy the same smoothing removes from the noise sample, both averaged
    in Gaussian windows (:func:`export.uncertainty.smoothing_window`): a flat or slowly varying area is
    smoothed wide, an edge or texture the noise cannot explain keeps its detail. The ink is not restored
    (the caller water-fills).
    """
    density = np.asarray(density, np.float64)
    noise = np.asarray(noise, np.float64)

    def excess(level: float, smooth: np.ndarray) -> np.ndarray:
        window = smoothing_window(level, config)
        removed_energy = gaussian_filter((density - smooth) ** 2, window)
        noise_energy = gaussian_filter((noise - gaussian_filter(noise, level)) ** 2 * noise_scale, window)
        return removed_energy / np.maximum(noise_energy, 1e-12) - NOISE_TOLERANCE

    return smoothing_ladder(density, excess, config)


def poisson_resample(density: np.ndarray, full_ink_per_px: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) an inhomogeneous Poisson pattern, in map pixel coordinates, of a map's ``density`` (H, W) in
    [0, 1] smoothed by :data:`RESAMPLE_SMOOTHING_PX`: ``density x full_ink_per_px`` points expected per pixel,
    each uniform in its pixel."""
    intensity = np.maximum(gaussian_filter(np.asarray(density, np.float64), RESAMPLE_SMOOTHING_PX), 0.0) * full_ink_per_px
    counts = rng.poisson(intensity)
    rows, columns = np.nonzero(counts)
    per_pixel = counts[rows, columns]
    rows, columns = np.repeat(rows, per_pixel), np.repeat(columns, per_pixel)
    return np.stack([columns + rng.random(len(columns)), rows + rng.random(len(rows))], axis=1)
