"""The in-memory map: a CIELAB image whose L is density and whose ab is correlation.

Conventions (SPEC §3):

* ``L`` in [0, 100]; density ``d = 1 - L / 100`` in [0, 1] (dark = many points).
* ``a``, ``b`` in [-128, 127]; latent correlation coordinate
  ``z = (ab + 128) / 255`` in [0, 1]^2, so that 8-bit values and the 256 x 256
  palette table coincide.
* The map covers the domain ``[0, w] x [0, h]`` with ``max(w, h) = 1``, origin at
  the top-left pixel corner, y pointing down. Pixel (row i, column j) covers
  ``[j, j+1] x [i, i+1]`` times ``1 / max(H, W)``.

Colour conversions are the CIE 1976 L*a*b* and IEC 61966-2-1 sRGB formulas with
the D65 white point (what ImageMagick uses for CIELAB TIFFs), written out in
numpy; they agree with colour-science to ~1e-6 (tests/test_mapio.py compares).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from synthesis.conventions import POINTS_PER_INK  # noqa: F401 - re-exported: the map convention n = POINTS_PER_INK * mean density
from synthesis.errors import MapFormatError

L_RANGE = (0.0, 100.0)
AB_RANGE = (-128.0, 127.0)
D65_XYZ = np.array([0.3127 / 0.3290, 1.0, (1.0 - 0.3127 - 0.3290) / 0.3290])  # white point, CIE 1931 2 deg, Y = 1
SRGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])  # IEC 61966-2-1
XYZ_TO_SRGB = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]])
_LAB_EPSILON = (24.0 / 116.0) ** 3  # CIE 1976: below this Y/Yn the cube root turns linear
_LAB_SLOPE = 841.0 / 108.0


def srgb_to_linear(srgb: np.ndarray) -> np.ndarray:
    """Decode sRGB values in [0, 1] to linear light (IEC 61966-2-1), float64, same shape."""
    srgb = np.asarray(srgb, dtype=np.float64)
    return np.where(srgb <= 0.04045, srgb / 12.92, ((np.maximum(srgb, 0.04045) + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """Encode linear light to sRGB values (IEC 61966-2-1), float64, same shape; negative input stays linear."""
    linear = np.asarray(linear, dtype=np.float64)
    return np.where(linear <= 0.0031308, linear * 12.92, 1.055 * np.maximum(linear, 0.0031308) ** (1.0 / 2.4) - 0.055)


def xyz_to_lab(xyz: np.ndarray) -> np.ndarray:
    """CIE XYZ (..., 3) with white Y = 1 -> CIELAB (..., 3) (L in [0, 100]), D65."""
    ratio = np.asarray(xyz, dtype=np.float64) / D65_XYZ
    f = np.where(ratio > _LAB_EPSILON, np.cbrt(ratio), _LAB_SLOPE * ratio + 16.0 / 116.0)
    return np.stack([116.0 * f[..., 1] - 16.0, 500.0 * (f[..., 0] - f[..., 1]), 200.0 * (f[..., 1] - f[..., 2])], axis=-1)


def lab_to_xyz(lab: np.ndarray) -> np.ndarray:
    """CIELAB (..., 3) -> CIE XYZ (..., 3) with white Y = 1, D65."""
    lab = np.asarray(lab, dtype=np.float64)
    f_y = (lab[..., 0] + 16.0) / 116.0
    f = np.stack([f_y + lab[..., 1] / 500.0, f_y, f_y - lab[..., 2] / 200.0], axis=-1)
    ratio = np.where(f > 24.0 / 116.0, f**3, (f - 16.0 / 116.0) / _LAB_SLOPE)
    return ratio * D65_XYZ


@dataclass(frozen=True, eq=False)
class LabMap:
    """A Patternshop map.

    Attributes:
        lab: (H, W, 3) float32 array; channel 0 is L in [0, 100], channels 1-2
            are a, b in [-128, 127]. Values are clipped into range on creation.
    """

    lab: np.ndarray

    def __post_init__(self) -> None:
        lab = np.asarray(self.lab, dtype=np.float32)
        if lab.ndim != 3 or lab.shape[2] != 3 or lab.shape[0] < 1 or lab.shape[1] < 1:
            raise MapFormatError(f"a map needs shape (H, W, 3), got {lab.shape}")
        if not np.all(np.isfinite(lab)):
            raise MapFormatError("map contains NaN or infinite values")
        lab = lab.copy()
        np.clip(lab[..., 0], *L_RANGE, out=lab[..., 0])
        np.clip(lab[..., 1:], *AB_RANGE, out=lab[..., 1:])
        lab.setflags(write=False)
        object.__setattr__(self, "lab", lab)

    # --- construction -----------------------------------------------------
    @classmethod
    def from_density_latent(cls, density: np.ndarray, latent: np.ndarray) -> LabMap:
        """Build a map from density (H, W) in [0, 1] and latent z (H, W, 2) in [0, 1]."""
        density = np.asarray(density, dtype=np.float32)
        latent = np.asarray(latent, dtype=np.float32)
        if latent.shape != density.shape + (2,):
            raise MapFormatError(f"latent shape {latent.shape} does not match density shape {density.shape} + (2,)")
        L = 100.0 * (1.0 - density)
        ab = 255.0 * latent - 128.0
        return cls(np.concatenate([L[..., None], ab], axis=-1))

    @classmethod
    def from_network(cls, output: np.ndarray) -> LabMap:
        """Build a map from the network's (3, H, W) output in [0, 1]: L/100, then the latent z (a, b)."""
        output = np.asarray(output, dtype=np.float32)
        return cls.from_density_latent(1.0 - output[0], output[1:].transpose(1, 2, 0))

    @classmethod
    def from_srgb(cls, rgb: np.ndarray) -> LabMap:
        """Convert an sRGB image (H, W, 3) with values in [0, 1] (D65) to a map."""
        return cls(xyz_to_lab(srgb_to_linear(rgb) @ SRGB_TO_XYZ.T))

    # --- views ------------------------------------------------------------
    @property
    def L(self) -> np.ndarray:
        """(H, W) lightness in [0, 100]."""
        return self.lab[..., 0]

    @property
    def ab(self) -> np.ndarray:
        """(H, W, 2) chroma coordinates a, b in [-128, 127]."""
        return self.lab[..., 1:]

    @property
    def height(self) -> int:
        return int(self.lab.shape[0])

    @property
    def width(self) -> int:
        return int(self.lab.shape[1])

    @property
    def domain(self) -> tuple[float, float]:
        """Domain size (w, h) in map units; the longer side is 1."""
        side = max(self.width, self.height)
        return self.width / side, self.height / side

    def density(self) -> np.ndarray:
        """(H, W) float32 density ``1 - L/100`` in [0, 1]; 1 is the darkest ink."""
        return 1.0 - self.L / 100.0

    def latent(self) -> np.ndarray:
        """(H, W, 2) float32 correlation latent ``z = (ab + 128) / 255`` in [0, 1]."""
        return (self.ab + 128.0) / 255.0

    def to_srgb(self) -> np.ndarray:
        """(H, W, 3) float64 sRGB in [0, 1] (D65), out-of-gamut colours clipped."""
        return np.clip(linear_to_srgb(lab_to_xyz(self.lab) @ XYZ_TO_SRGB.T), 0.0, 1.0)

    def to_srgb8(self) -> np.ndarray:
        """(H, W, 3) uint8 sRGB of :meth:`to_srgb`, for previews."""
        return np.rint(self.to_srgb() * 255.0).astype(np.uint8)

    def __repr__(self) -> str:
        w, h = self.domain
        return f"LabMap({self.width}x{self.height} px, domain {w:.4g} x {h:.4g})"


def resample_channel(channel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float32 of a channel (h, w) resampled to ``shape`` (H, W): bilinear, antialiased when shrinking."""
    if channel.shape == shape:
        return np.asarray(channel, np.float32)
    from PIL import Image

    image = Image.fromarray(np.ascontiguousarray(channel, np.float32)).resize((shape[1], shape[0]), Image.Resampling.BILINEAR)
    return np.asarray(image, np.float32)


def resample_map(lab_map: LabMap, shape: tuple[int, int]) -> LabMap:
    """A new map: ``lab_map`` resampled to ``shape`` (H, W), channel by channel (:func:`resample_channel`)."""
    return LabMap(np.stack([resample_channel(lab_map.lab[..., c], shape) for c in range(3)], axis=-1))


def pixels_of(xy: np.ndarray, shape: tuple[int, int], side: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) int64 arrays (n,): the pixel of a map of ``shape`` (H, W) that each (n, 2) point in domain units
    (long side 1, origin top-left) lies in, clipped to the map; ``side``: pixels per domain unit (default max(shape))."""
    side = max(shape) if side is None else side
    col = np.clip((xy[:, 0] * side).astype(np.int64), 0, shape[1] - 1)
    row = np.clip((xy[:, 1] * side).astype(np.int64), 0, shape[0] - 1)
    return row, col
