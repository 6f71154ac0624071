"""Gaussian blur of a map without scipy: ``scipy.ndimage.gaussian_filter`` (mode 'reflect') as matrix products or
through numpy's FFT.

``infer`` blurs maps in two places (the density estimate that picks the pattern's scale,
:func:`export.evidence.local_density`, and the smoothing ladder, :mod:`export.uncertainty`, 13 blurs a map). With
scipy's filter, importing ``scipy.ndimage`` was a fifth of a 20,000-point ``infer`` (0.19 s of about 1 s: scipy's
array-API layer imports numpy.f2py, numpy.ma and numpy.testing). :func:`gaussian` blurs a map of up to
:data:`MATRIX_MAX_SIDE` px a side as ``M_h @ image @ M_w.T`` in float32 (:func:`blur_matrix`: the 1-D filter with
its reflection folded in); larger ones, and :func:`gaussian_fft`, its reference, through numpy's FFT of the mirrored
map (float64). On a 256-px map one blur takes 0.5 ms as products against 1.4-2.6 ms through the FFT (one thread;
4 and 16 px). ``tests/test_gaussian.py`` compares both with scipy's filter.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


def _fast_length(n: int) -> int:
    """The smallest length >= ``n`` with no prime factor above 5 (a fast FFT length)."""
    while True:
        m = n
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        if m == 1:
            return n
        n += 1


@lru_cache(maxsize=64)
def _transfer(sigma: float, radius: int, length: int, real: bool) -> np.ndarray:
    """The DFT of scipy's truncated Gaussian kernel (``radius`` px each side, summing to 1) wrapped around ``length``."""
    x = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 / (sigma * sigma) * x**2)
    wrapped = np.zeros(length)
    wrapped[np.mod(x, length)] = kernel / kernel.sum()
    transfer = np.fft.rfft(wrapped) if real else np.fft.fft(wrapped)
    transfer.flags.writeable = False  # shared by the cache
    return transfer


MATRIX_MAX_SIDE = 640  # maps up to this side (px) are blurred by matrix products; beyond, through the FFT (as fast at
# 768-1024 px: 12.5 against 10.6-21 ms, 30 against 26-33 ms; 3.7 against 6.7-8.0 ms at 512; one thread, a shared machine)


@lru_cache(maxsize=32)
def blur_matrix(sigma: float, radius: int, length: int) -> np.ndarray:
    """(length, length) float32 M: ``M @ v`` is scipy's ``gaussian_filter1d`` of a vector v of ``length`` (kernel
    ``radius`` px each side, summing to 1, mode 'reflect': ``d c b a | a b c d | d c b a``, repeated where the kernel
    is wider than the vector)."""
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 / (sigma * sigma) * offsets**2)
    rows = np.arange(length)
    columns = np.mod(rows[:, None] + offsets, 2 * length)
    columns = np.where(columns < length, columns, 2 * length - 1 - columns)
    matrix = np.zeros((length, length))
    np.add.at(matrix, (np.broadcast_to(rows[:, None], columns.shape), columns), kernel / kernel.sum())
    matrix = matrix.astype(np.float32)
    matrix.flags.writeable = False  # shared by the cache
    return matrix


def gaussian(image: np.ndarray, sigma: float, truncate: float = 4.0) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter(image, sigma, truncate=truncate)`` of a map (H, W), mode 'reflect', float64:
    within 1e-6 of scipy's on maps in [0, 1] (float32 products) up to :data:`MATRIX_MAX_SIDE` px a side, else
    :func:`gaussian_fft`. ``sigma`` in px, > 0."""
    image = np.asarray(image, np.float64)
    radius = int(truncate * sigma + 0.5)
    if radius == 0:
        return image.copy()
    h, w = image.shape
    if max(h, w) > MATRIX_MAX_SIDE:
        return gaussian_fft(image, sigma, truncate)
    blurred = blur_matrix(sigma, radius, h) @ image.astype(np.float32) @ blur_matrix(sigma, radius, w).T
    return blurred.astype(np.float64)


def gaussian_fft(image: np.ndarray, sigma: float, truncate: float = 4.0) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter(image, sigma, truncate=truncate)`` of a map (H, W), float64, mode 'reflect'.

    The kernel is scipy's (``int(truncate * sigma + 0.5)`` px each side, normalised to sum 1), applied through the
    FFT of the map mirrored by that radius (``np.pad``'s 'symmetric' is scipy's 'reflect', repeated where the kernel
    is wider than the map); the values agree with scipy's within rounding (1e-14 on maps in [0, 1]).
    ``sigma`` in px, > 0.
    """
    image = np.asarray(image, np.float64)
    radius = int(truncate * sigma + 0.5)
    if radius == 0:
        return image.copy()
    h, w = image.shape
    shape = (_fast_length(h + 2 * radius), _fast_length(w + 2 * radius))
    spectrum = np.fft.rfft2(np.pad(image, radius, mode="symmetric"), s=shape)
    spectrum *= _transfer(sigma, radius, shape[0], real=False)[:, None] * _transfer(sigma, radius, shape[1], real=True)
    return np.fft.irfft2(spectrum, s=shape)[radius : radius + h, radius : radius + w]
