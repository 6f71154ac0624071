"""Gaussian blur of a map through numpy's FFT: ``scipy.ndimage.gaussian_filter`` (mode 'reflect') without scipy.

``infer`` blurs maps in two places (the density estimate that picks the pattern's scale,
:func:`export.evidence.local_density`, and the smoothing ladder, :mod:`export.uncertainty`). With scipy's filter,
importing ``scipy.ndimage`` was a fifth of a 20,000-point ``infer`` (0.19 s of about 1 s: scipy's array-API layer
imports numpy.f2py, numpy.ma and numpy.testing); through numpy's FFT the blur costs about as much (1.4 ms on a
256-px map at any width) and the import nothing. ``tests/test_gaussian.py`` compares it with scipy's filter, its
reference.
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


def gaussian(image: np.ndarray, sigma: float, truncate: float = 4.0) -> np.ndarray:
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
