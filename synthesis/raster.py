"""The network's view of a point pattern: a bilinear point-count raster.

One function, :func:`point_raster`, used both to make training pairs
(:mod:`data_gen.pairs`) and at inference, so the network always sees the same
thing. The raster covers the unit square ``[0, 1]^2`` with ``size`` pixels per
side (pixel ``(i, j)`` covers ``[j, j+1] x [i, i+1] / size``, y down as in the
maps); a domain ``[0, w] x [0, h]`` with ``max(w, h) = 1`` therefore fills the
top-left ``w * size`` x ``h * size`` pixels and the rest stays 0.

Each point adds a unit mass split bilinearly over the four pixels around it
(so positions below a pixel still show), and the sums are clipped to [0, 1].
At the default model's scale (8,000 points per ink on 256 x 256 pixels) a
fully black region holds about 0.12 points per pixel, so the clip almost never
binds; it only bounds the input range.
"""

from __future__ import annotations

import numpy as np

RASTER_SIZE = 256  # pixels per side of the network input (paper: 256 x 256)


def point_raster(xy: np.ndarray, size: int = RASTER_SIZE, clip: bool = True) -> np.ndarray:
    """(size, size) float32 raster in [0, 1] of points xy (n, 2) in map units (see module docstring).

    Points outside ``[0, 1]^2`` are clamped onto the border pixels. ``clip=False`` keeps the sums (points per
    pixel, any value >= 0): a density estimate's input, free of the aliasing that binning a regular pattern
    into pixels gives.
    """
    if size < 2:
        raise ValueError(f"raster size must be at least 2, got {size}")
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    stride = size + 1  # one spare row and column take the right/bottom taps of the last pixels
    raster = np.zeros(stride * stride)
    if len(xy):
        position = np.clip(xy * size - 0.5, 0.0, size - 1.0)  # pixel-centre coordinates
        lower = np.floor(position).astype(np.int64)
        tc, tr = (position - lower).T
        base = lower[:, 1] * stride + lower[:, 0]
        taps = np.concatenate([base, base + 1, base + stride, base + stride + 1])
        weights = np.concatenate([(1 - tr) * (1 - tc), (1 - tr) * tc, tr * (1 - tc), tr * tc])
        raster = np.bincount(taps, weights, minlength=stride * stride)
    raster = raster.reshape(stride, stride)[:size, :size]
    return (np.clip(raster, 0.0, 1.0) if clip else raster).astype(np.float32)
