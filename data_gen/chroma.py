"""Random correlation (chroma) fields for training maps (SPEC §2.4, supplemental §1.3).

Every field is a latent map z (H, W, 2) in [0, 1]^2 (``a, b = 255 z - 128``)
whose values lie in the palette's populated region
(:meth:`synthesis.palette.Palette.sample_latents`), so no training map asks
for a correlation no exemplar realises.

* :func:`uniform_chroma` — one random latent everywhere.
* :func:`segment_chroma` — one random latent per segment of a label image.
* :func:`gaussian_field_chroma` — a smooth field: 2-16 anisotropic Gaussians
  (centre uniform in [0, 1]^2, angle in [-180, 180] degrees, standard
  deviations in [0.15, 0.25] map units per axis), each carrying a random
  latent, blended with the normalised Gaussian weights (equal weight per
  kernel), then snapped back into the populated region where a blend leaves it.
"""

from __future__ import annotations

import numpy as np

from synthesis.palette import Palette


def uniform_chroma(shape: tuple[int, int], rng: np.random.Generator, palette: Palette) -> np.ndarray:
    """(H, W, 2) float32: one random populated latent everywhere."""
    return np.broadcast_to(palette.sample_latents(rng, 1)[0], tuple(shape) + (2,)).astype(np.float32)


def segment_chroma(labels: np.ndarray, rng: np.random.Generator, palette: Palette) -> np.ndarray:
    """(H, W, 2) float32: a random populated latent per distinct value of ``labels`` (H, W) int."""
    values, inverse = np.unique(labels, return_inverse=True)
    latents = palette.sample_latents(rng, len(values))
    return latents[inverse.reshape(labels.shape)].astype(np.float32)


def gaussian_field_chroma(
    shape: tuple[int, int],
    rng: np.random.Generator,
    palette: Palette,
    kernels: tuple[int, int] = (2, 16),
    sizes: tuple[float, float] = (0.15, 0.25),
) -> np.ndarray:
    """(H, W, 2) float32 smooth latent field of random anisotropic Gaussians (see module docstring)."""
    height, width = shape
    side = max(height, width)
    rows, cols = np.mgrid[0:height, 0:width]
    xy = np.stack([(cols + 0.5) / side, (rows + 0.5) / side], -1)
    count = int(rng.integers(kernels[0], kernels[1] + 1))
    latents = palette.sample_latents(rng, count)
    weight_sum = np.zeros(shape)
    field = np.zeros(tuple(shape) + (2,))
    for latent in latents:
        centre = rng.random(2)
        angle = np.radians(rng.uniform(-180.0, 180.0))
        sigma = rng.uniform(*sizes, size=2)
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        local = (xy - centre) @ rotation  # coordinates along the kernel's axes
        weight = np.exp(-0.5 * ((local / sigma) ** 2).sum(-1))
        weight_sum += weight
        field += weight[..., None] * latent
    field /= np.maximum(weight_sum, 1e-300)[..., None]
    return palette.snap_to_populated(field).astype(np.float32)
