"""Radial power spectra of point sets on the unit torus, and fitting points to one.

Conventions: points ``x`` (n, 2) in [0, 1)^2 with periodic boundaries; integer
frequencies ``k`` in Z^2 (cycles per domain side); the power spectrum
``P(k) = |sum_j exp(-2 pi i k.x_j)|^2 / n`` (1 for a Poisson pattern); the radial
spectrum ``P_b`` averages ``P(k)`` over ``round(|k|) = b`` for b = 0..B-1, with the
DC bin ``P_0`` left at 0.

Transforms are non-uniform FFTs (finufft): a type-1 transform gives ``F(k)``,
and the gradient of a spectrum loss with respect to the positions is one type-2
transform, so a loss and its gradient cost O(n + B^2 log B) instead of the
O(n B^2) of a direct sum (the differentiable spectrum of Leimkühler et al. 2019).
"""

from __future__ import annotations

from dataclasses import dataclass

import finufft
import numpy as np

SPECTRUM_BINS = 64  # b = 0..63, as in the paper's supplemental 1.1


class RadialSpectrum:
    """Radial power spectrum and spectrum-matching loss for point sets of a fixed size.

    Args:
        n: number of points the transforms are planned for.
        bins: number B of radial bins b = 0..B-1.
        eps: NUFFT relative accuracy.
    """

    def __init__(self, n: int, bins: int = SPECTRUM_BINS, eps: float = 1e-6) -> None:
        self.n = n
        self.bins = bins
        half = bins
        modes = (2 * half + 1, 2 * half + 1)
        k = np.arange(-half, half + 1)
        self._kx, self._ky = np.meshgrid(k, k, indexing="ij")
        radial = np.rint(np.hypot(self._kx, self._ky)).astype(np.int64)
        self._in_range = (radial >= 1) & (radial < bins)
        self._bin = radial[self._in_range]
        self._count = np.bincount(self._bin, minlength=bins).astype(np.float64)
        self._type1 = finufft.Plan(1, modes, eps=eps, isign=-1, nthreads=1)
        self._type2 = finufft.Plan(2, modes, n_trans=2, eps=eps, isign=-1, nthreads=1)
        self._ones = np.ones(n, np.complex128)

    def _transform(self, points: np.ndarray) -> np.ndarray:
        if points.shape != (self.n, 2):
            raise ValueError(f"expected ({self.n}, 2) points, got {points.shape}")
        angles = 2.0 * np.pi * np.asarray(points, np.float64)
        self._type1.setpts(angles[:, 0].copy(), angles[:, 1].copy())
        self._type2.setpts(angles[:, 0].copy(), angles[:, 1].copy())
        return self._type1.execute(self._ones)

    def _radial(self, fourier: np.ndarray) -> np.ndarray:
        power = (fourier.real**2 + fourier.imag**2) / self.n
        total = np.bincount(self._bin, weights=power[self._in_range], minlength=self.bins)
        return total / np.maximum(self._count, 1.0)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(B,) radial power spectrum of (n, 2) torus points; entry 0 is 0."""
        return self._radial(self._transform(points))

    def loss_and_gradient(self, points: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """Squared error ``sum_b (P_b - target_b)^2`` over b >= 1, its (n, 2) gradient, and P.

        Args:
            points: (n, 2) positions in [0, 1)^2.
            target: (B,) target radial spectrum (entry 0 ignored).
        """
        fourier = self._transform(points)
        spectrum = self._radial(fourier)
        residual = spectrum - target
        residual[0] = 0.0
        weight = np.zeros(fourier.shape)
        weight[self._in_range] = 2.0 * residual[self._bin] / self._count[self._bin] / self.n
        conj = weight * np.conj(fourier)
        # d|F(k)|^2/dx_j = 2 Re(conj F(k) (-2 pi i k) e^{-2 pi i k.x_j}) -> one type-2 NUFFT per axis
        summed = self._type2.execute(np.stack([self._kx * conj, self._ky * conj]))
        gradient = 4.0 * np.pi * np.imag(summed).T
        return float(np.sum(residual**2)), gradient, spectrum


@dataclass(frozen=True)
class SpectrumFit:
    """Result of :func:`fit_spectrum`: points (n, 2) in [0,1)^2, their spectrum, RMS error over b >= 1."""

    points: np.ndarray
    spectrum: np.ndarray
    rms_error: float


def fit_spectrum(
    target: np.ndarray,
    n: int,
    rng: np.random.Generator,
    iterations: int = 200,
    learning_rate: float = 2e-3,
    spectrum: RadialSpectrum | None = None,
) -> SpectrumFit:
    """Find n torus points whose radial power spectrum matches ``target`` (B,).

    Adam on the positions from a uniform random start, with a cosine-decayed
    learning rate (in domain units); positions wrap around the torus.
    """
    spectrum = spectrum or RadialSpectrum(n, len(target))
    target = np.asarray(target, np.float64)
    points = rng.random((n, 2))
    first, second = np.zeros_like(points), np.zeros_like(points)
    beta1, beta2 = 0.9, 0.999
    for step in range(1, iterations + 1):
        _, gradient, _ = spectrum.loss_and_gradient(points, target)
        first = beta1 * first + (1 - beta1) * gradient
        second = beta2 * second + (1 - beta2) * gradient**2
        rate = learning_rate * 0.5 * (1.0 + np.cos(np.pi * (step - 1) / iterations))
        update = (first / (1 - beta1**step)) / (np.sqrt(second / (1 - beta2**step)) + 1e-12)
        points = np.mod(points - rate * update, 1.0)
    loss, _, realised = spectrum.loss_and_gradient(points, target)
    return SpectrumFit(points, realised, float(np.sqrt(loss / (len(target) - 1))))
