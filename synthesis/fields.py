"""Per-map fields the edge-aware estimator and the synthesiser sample at points.

A :class:`MapFields` holds, on the map's pixel grid: the intensity (points per
unit area) implied by the density and the point count, the local spacing
``r_max(x)`` in which distances are measured, the latent correlation z (the
guide), the target PCF from the palette, and the estimator's denominator (the
kernel sum a Poisson pattern of that intensity would give, computed once per
map by quadrature; it corrects the domain border and sharp edges).

Grids are (H, W, C) float32; pixel (i, j) is centred at ((j + .5) / S, (i + .5) / S)
with S = max(H, W), so the map covers ``[0, w] x [0, h]`` with max(w, h) = 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from synthesis.errors import PatternshopError
from synthesis.labmap import LabMap
from synthesis.palette import Palette
from synthesis.pcf import KERNEL_SIGMA, neighbour_cutoff, pcf_radii, r_max, radial_kernel, uniform_expectation

GUIDE_BANDWIDTH = 0.005  # variance of the guide (latent z) similarity, per dimension
DENSITY_FLOOR = 1e-3  # relative to the mean density: keeps spacings finite in white areas
QUADRATURE_RADII = 14  # nodes over [0, cutoff]: steps of 0.77 sigma
QUADRATURE_ANGLES = 20
FIELD_MAX_SIDE = 256  # fields are computed on the map resampled to at most this many pixels per side


def sample_grid(grid: torch.Tensor, xy: torch.Tensor, side_px: int) -> torch.Tensor:
    """Bilinear samples (n, C) of a (H, W, C) grid at positions xy (n, 2) in map units.

    Positions outside the grid take the nearest edge value.
    """
    height, width, channels = grid.shape
    col = (xy[:, 0] * side_px - 0.5).clamp(0, width - 1)
    row = (xy[:, 1] * side_px - 0.5).clamp(0, height - 1)
    c0 = col.floor().long().clamp(max=max(width - 2, 0))
    r0 = row.floor().long().clamp(max=max(height - 2, 0))
    c1 = (c0 + 1).clamp(max=width - 1)
    r1 = (r0 + 1).clamp(max=height - 1)
    tc = (col - c0).unsqueeze(1)
    tr = (row - r0).unsqueeze(1)
    top = grid[r0, c0] * (1 - tc) + grid[r0, c1] * tc
    bottom = grid[r1, c0] * (1 - tc) + grid[r1, c1] * tc
    return top * (1 - tr) + bottom * tr


def _at_most(lab_map: LabMap, side: int) -> LabMap:
    """The map area-averaged so its longer side has at most ``side`` pixels (same domain)."""
    longest = max(lab_map.width, lab_map.height)
    if longest <= side:
        return lab_map
    size = (max(1, round(lab_map.height * side / longest)), max(1, round(lab_map.width * side / longest)))
    lab = torch.from_numpy(np.array(lab_map.lab)).permute(2, 0, 1)[None]
    return LabMap(F.interpolate(lab, size=size, mode="area")[0].permute(1, 2, 0).numpy())


def guide_similarity(z_a: torch.Tensor, z_b: torch.Tensor, bandwidth: float = GUIDE_BANDWIDTH) -> torch.Tensor:
    """Guidance term H = exp(-|z_a - z_b|^2 / (2 bandwidth)) over the last axis (latent z)."""
    return torch.exp(-((z_a - z_b) ** 2).sum(-1) / (2.0 * bandwidth))


@dataclass
class MapFields:
    """Fields of one map for n points (see the module docstring).

    Attributes:
        domain: (w, h).
        side_px: pixels per map unit (max(H, W)).
        n: number of points.
        intensity: (H, W, 1) points per unit area.
        spacing: (H, W, 1) local r_max.
        latent: (H, W, 2) guide z in [0, 1].
        target: (H, W, m) target PCF.
        denominator: (H, W, m) expected kernel sums of a Poisson pattern.
        radii: (m,) radii in units of r_max.
    """

    domain: tuple[float, float]
    side_px: int
    n: int
    intensity: torch.Tensor
    spacing: torch.Tensor
    latent: torch.Tensor
    target: torch.Tensor
    denominator: torch.Tensor
    radii: np.ndarray
    guide: bool = True

    @classmethod
    def build(cls, lab_map: LabMap, n: int, palette: Palette, guide: bool = True, sigma: float = KERNEL_SIGMA) -> MapFields:
        """Precompute every field of ``lab_map`` for ``n`` points (``guide=False``: no guidance term).

        Maps larger than :data:`FIELD_MAX_SIDE` pixels per side are area-averaged
        down first; the fields are smooth on that scale and the denominator's
        cost grows with the pixel count.
        """
        w, h = lab_map.domain  # of the original map: resampling rounds the pixel counts
        lab_map = _at_most(lab_map, FIELD_MAX_SIDE)
        density = lab_map.density().astype(np.float64)
        if not np.any(density > 0):
            raise PatternshopError("the map is white everywhere: there is nothing to place points on")
        if n < 1:
            raise PatternshopError(f"point count must be at least 1, got {n}")
        density = np.maximum(density, DENSITY_FLOOR * density.mean())
        intensity = n * density / (density.mean() * w * h)
        spacing = r_max(intensity)  # points per unit area -> local r_max
        radii = pcf_radii()
        latent = lab_map.latent().astype(np.float32)
        target = palette.pcf_at_latent(latent)
        fields = cls(
            domain=(w, h), side_px=max(lab_map.width, lab_map.height), n=n,
            intensity=torch.from_numpy(intensity[..., None].astype(np.float32)),
            spacing=torch.from_numpy(spacing[..., None].astype(np.float32)),
            latent=torch.from_numpy(latent), target=torch.from_numpy(target.astype(np.float32)),
            denominator=torch.empty(0), radii=radii, guide=guide,
        )
        fields.denominator = fields._poisson_denominator(sigma)
        return fields

    def _poisson_denominator(self, sigma: float) -> torch.Tensor:
        """(H, W, m) ``int lambda(y) N(|y - x| / s(x); rho, sigma) H(y, x) dy`` over the domain.

        Polar quadrature around every pixel centre x in units of s(x), with
        lambda = 0 outside the domain. The result is the ratio to
        the same quadrature of an unbounded uniform field times the exact
        unbounded value ``lambda(x) s(x)^2 E(rho)``, so quadrature error cancels
        wherever the neighbourhood is uniform and only edges and borders move it.
        """
        height, width, _ = self.intensity.shape
        radii = self.radii
        cutoff = neighbour_cutoff(radii, sigma)
        step = cutoff / QUADRATURE_RADII
        u = (np.arange(QUADRATURE_RADII) + 0.5) * step
        theta = (np.arange(QUADRATURE_ANGLES) + 0.5) * (2 * math.pi / QUADRATURE_ANGLES)
        uu, tt = (a.reshape(-1) for a in np.meshgrid(u, theta, indexing="ij"))
        kernel = radial_kernel(uu, radii, sigma) * (uu * step * 2 * math.pi / QUADRATURE_ANGLES)[:, None]  # (Q, m)
        kernel_t = torch.from_numpy(kernel.astype(np.float32))
        free = kernel_t.sum(0)  # quadrature of the unbounded uniform case
        exact = torch.from_numpy(uniform_expectation(radii, sigma, cutoff).astype(np.float32))
        # offsets in grid_sample's normalised coordinates per unit of spacing
        to_grid = torch.tensor([2.0 * self.side_px / width, 2.0 * self.side_px / height])
        offsets = torch.from_numpy(np.stack([uu * np.cos(tt), uu * np.sin(tt)], -1).astype(np.float32)) * to_grid
        rows, cols = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
        base = torch.stack([(cols.reshape(-1) + 0.5) / width * 2 - 1, (rows.reshape(-1) + 0.5) / height * 2 - 1], -1)
        fields = torch.cat([self.intensity, self.latent], -1).permute(2, 0, 1)[None]  # (1, 3, H, W)
        flat_spacing = self.spacing.reshape(-1, 1, 1)
        flat_intensity = self.intensity.reshape(-1, 1)
        flat_latent = self.latent.reshape(-1, 1, 2)
        out = torch.empty(height * width, len(radii))
        chunk = max(1, 4_000_000 // len(offsets))
        for start in range(0, len(base), chunk):
            block = slice(start, start + chunk)
            grid = base[block, None, :] + flat_spacing[block] * offsets[None]  # (P, Q, 2)
            sampled = F.grid_sample(fields, grid[None], mode="bilinear", padding_mode="border", align_corners=False)[0]
            inside = (grid.abs() <= 1.0).all(dim=-1)
            weight = sampled[0] * inside  # lambda(y), 0 outside the domain
            if self.guide:
                weight = weight * guide_similarity(sampled[1:].permute(1, 2, 0), flat_latent[block])
            out[block] = (weight @ kernel_t) / (free * flat_intensity[block])
        scale = self.intensity * self.spacing**2 * exact
        return out.reshape(height, width, -1) * scale

    # --- sampling at points -------------------------------------------------
    def at(self, xy: torch.Tensor) -> dict[str, torch.Tensor]:
        """Fields at positions xy (n, 2): spacing (n,), latent (n, 2), target and denominator (n, m)."""
        return {
            "spacing": sample_grid(self.spacing, xy, self.side_px)[:, 0],
            "latent": sample_grid(self.latent, xy, self.side_px),
            "target": sample_grid(self.target, xy, self.side_px),
            "denominator": sample_grid(self.denominator, xy, self.side_px),
        }
