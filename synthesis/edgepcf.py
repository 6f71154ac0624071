"""The edge-aware PCF estimator (paper §5) and the synthesis objective's gradient.

At a centre point c of the pattern and radius rho_j (units of the local spacing
s(c) = r_max at c):

    g_hat(c, rho_j) = sum_k N(|x_k - x_c| / s(c); rho_j, sigma) H(z(x_k), z(x_c))  /  D(c, rho_j)

over c's k = 50 nearest neighbours within the kernel's reach, where H is the
guidance term on the latent correlation z and D the Poisson denominator of
:class:`~synthesis.fields.MapFields` (which corrects borders and edges). For an
(inhomogeneous) Poisson pattern with the map's density, E[g_hat] = 1 everywhere.

Centres are points of the pattern, not arbitrary locations: around an arbitrary
location the expected neighbour count is the same for every stationary
pattern (it measures the contact distribution, not the pair correlation), so a
PCF is only observable around points.

The objective of paper eq. 6 is ``mean_{c, j} (g_hat(c, rho_j) - g(c, rho_j))^2``
with the target g from the palette. Its gradient with respect to the positions
is written out by hand (chain rule through the pair distances) so memory stays
O(n k) and no autograd graph of size n x k x m is kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from synthesis.fields import MapFields, guide_similarity
from synthesis.labmap import LabMap
from synthesis.palette import Palette
from synthesis.pcf import KERNEL_SIGMA, NEIGHBOURS, neighbour_cutoff

CHUNK = 8192  # centres per block, bounds the (chunk, k, m) temporaries


@dataclass
class Neighbourhoods:
    """Neighbour lists and the fields sampled at the centres, refreshed every few steps.

    Attributes:
        centres: (C,) indices of the centre points.
        neighbours: (C, k) indices of their nearest other points.
        spacing: (C,) local r_max at the centres.
        target, denominator: (C, m).
        guide: (C, k) guidance weights H between each centre and its neighbours.
    """

    centres: torch.Tensor
    neighbours: torch.Tensor
    spacing: torch.Tensor
    target: torch.Tensor
    denominator: torch.Tensor
    guide: torch.Tensor


def find_neighbourhoods(fields: MapFields, xy: torch.Tensor, centres: torch.Tensor, k: int = NEIGHBOURS) -> Neighbourhoods:
    """k nearest neighbours (k-d tree) of the given centre points and the fields there."""
    points = xy.numpy()
    k = min(k, len(points) - 1)
    _, index = cKDTree(points).query(points[centres.numpy()], k=k + 1)
    neighbours = torch.from_numpy(np.asarray(index, np.int64).reshape(len(centres), k + 1)[:, 1:])
    at_centres = fields.at(xy[centres])
    if fields.guide:
        latent = fields.at(xy)["latent"]
        guide = guide_similarity(latent[neighbours], at_centres["latent"][:, None, :])
    else:
        guide = torch.ones(neighbours.shape)
    return Neighbourhoods(centres, neighbours, at_centres["spacing"], at_centres["target"], at_centres["denominator"], guide)


BIN_WIDTH = 0.02  # fine histogram of normalised pair distances (sigma / 13)


def _kernel_tables(radii: np.ndarray, sigma: float, cutoff: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Kernel N(u; rho_j, sigma) and its u-derivative on the fine grid u_b = b * BIN_WIDTH: (B, m) each."""
    u = np.arange(int(np.ceil(cutoff / BIN_WIDTH)) + 2) * BIN_WIDTH
    delta = u[:, None] - radii[None, :]
    value = np.exp(-0.5 * (delta / sigma) ** 2) / (sigma * np.sqrt(2 * np.pi))
    return torch.from_numpy(value.astype(np.float32)), torch.from_numpy((-delta / sigma**2 * value).astype(np.float32))


def estimate(fields: MapFields, xy: torch.Tensor, hood: Neighbourhoods, sigma: float = KERNEL_SIGMA) -> torch.Tensor:
    """Edge-aware PCF (C, m) at the centres of ``hood`` for positions xy (n, 2)."""
    return _objective(fields, xy, hood, sigma, gradient=False)[1]


def local_errors(lab_map: LabMap, points: np.ndarray, n: int | None = None,
                 palette: Palette | None = None) -> tuple[np.ndarray, MapFields]:
    """(n,) mean-over-radii |edge-aware PCF - target| at every point (n, 2) of a pattern on ``lab_map``, and the fields.

    The map's target PCFs come from ``palette`` (default: the shipped one); ``n``
    sets the map's point spacing (default: the pattern's own count).
    """
    from synthesis.palette import load_palette

    fields = MapFields.build(lab_map, len(points) if n is None else n, palette or load_palette())
    xy = torch.from_numpy(np.asarray(points, np.float32))
    hood = find_neighbourhoods(fields, xy, torch.arange(len(xy)))
    return (estimate(fields, xy, hood) - hood.target).abs().mean(dim=1).numpy(), fields


def loss_and_gradient(
    fields: MapFields, xy: torch.Tensor, hood: Neighbourhoods, sigma: float = KERNEL_SIGMA
) -> tuple[float, torch.Tensor]:
    """Objective ``mean (g_hat - g)^2`` over centres and radii, and its gradient (n, 2)."""
    loss, _, gradient = _objective(fields, xy, hood, sigma, gradient=True)
    return loss, gradient


def _objective(fields: MapFields, xy: torch.Tensor, hood: Neighbourhoods, sigma: float, gradient: bool):
    """Estimates, objective and gradient in one pass.

    Pair distances are spread linearly onto a fine histogram per centre
    (:data:`BIN_WIDTH`), and the histogram times the kernel table gives the
    kernel sums for all m radii: O(1) work per pair instead of O(m). The
    gradient reads the kernel derivative back from the same grid.
    """
    cutoff = neighbour_cutoff(fields.radii, sigma)
    table, slope_table = _kernel_tables(fields.radii, sigma, cutoff)
    bins, m = table.shape
    count = len(hood.centres)
    grad = torch.zeros_like(xy) if gradient else None
    estimates = torch.empty(count, m)
    total = 0.0
    for start in range(0, count, CHUNK):
        block = slice(start, start + CHUNK)
        centres, neighbours = hood.centres[block], hood.neighbours[block]
        offset = xy[neighbours] - xy[centres][:, None, :]  # (c, k, 2)
        distance = offset.norm(dim=-1).clamp_min(1e-12)
        position = distance / (hood.spacing[block, None] * BIN_WIDTH)
        weight = hood.guide[block] * (position <= cutoff / BIN_WIDTH)
        lower = position.floor().clamp(max=bins - 2)
        frac = (position - lower).clamp(max=1.0)
        lower = lower.long()
        histogram = torch.zeros(len(centres), bins)
        histogram.scatter_add_(1, lower, weight * (1 - frac)).scatter_add_(1, lower + 1, weight * frac)
        estimate_block = (histogram @ table) / hood.denominator[block]
        estimates[block] = estimate_block
        residual = estimate_block - hood.target[block]
        total += float((residual**2).sum())
        if gradient:
            d_estimate = 2.0 * residual / (hood.denominator[block] * count * m)  # (c, m)
            d_grid = d_estimate @ slope_table.T  # dL/du on the fine grid, (c, B)
            d_u = (d_grid.gather(1, lower) * (1 - frac) + d_grid.gather(1, lower + 1) * frac) * weight
            pull = (d_u / (distance * hood.spacing[block, None]))[..., None] * offset  # dL/dx_k
            grad.index_add_(0, neighbours.reshape(-1), pull.reshape(-1, 2))
            grad.index_add_(0, centres, -pull.sum(1))
    return total / (count * m), estimates, grad
