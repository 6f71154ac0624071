"""The correlation palette: a 2D perceptual colour space of point correlations.

Built once by ``python -m data_gen.palette`` (see there and SPEC §2.1) and
shipped as ``synthesis/assets/palette.npz`` with a provenance record
``palette.json`` and the exemplars' nearest-neighbour bounds ``palette_neighbours.npz``
(:func:`read_neighbour_table`) beside it. At run time it answers two questions:

* **encode** — which PCF does the chroma (a, b) stand for? :meth:`Palette.pcf`
  samples the 256 x 256 x m look-up table bilinearly, so 8-bit, 16-bit and
  float maps all work (the 8-bit grid points are the table entries).
* **decode** — which chroma describes this point pattern? :meth:`Palette.locate`
  measures its PCF, coarse-grained to bins of :data:`DECODE_BIN_WIDTH` r_max
  (:func:`pcf_code`; the exemplars' codes come from their stored PCFs the same
  way), and interpolates between the coordinates of the
  :data:`DECODE_NEIGHBOURS` nearest exemplars (inverse-distance weights, power
  :data:`DECODE_POWER`), so nearby patterns get nearby colours rather than the
  same exemplar's or a jump (the paper's eq. 5 takes the nearest exemplar
  alone). A PCF depends on distances only, so a pattern keeps its colour when
  it is turned or shifted; the layout itself was built from CNN features,
  which depend on orientation (docs/palette.md). How far the nearest exemplar
  is, in units of the corpus's own exemplar spacing, says how much the colour
  can be trusted: beyond :data:`OUTSIDE_CORPUS` the pattern is unlike anything
  the palette was built from.

Latent ``z`` in [0, 1]^2 and chroma relate by ``a, b = 255 z - 128``.
"""

from __future__ import annotations

import contextlib
import functools
import glob
import io
import json
import os
import tempfile
import zipfile
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synthesis.errors import PatternshopError, require_file

ASSET_DIR = Path(__file__).resolve().parent / "assets"
DEFAULT_PALETTE = ASSET_DIR / "palette.npz"
FORMAT_VERSION = 3  # 2: exemplar_spectrum added; 3: tent-binned PCFs from r = 0, count dispersion table
LUT_SIZE = 256
DISPERSION_LUT_SIZE = 64  # the dispersion table varies slowly: 64 x 64 nodes
POPULATED_RADIUS = 0.03  # latent distance to the nearest exemplar within which a colour counts as populated
POPULATED_GRID = 64  # cells per side of the grid the populated region is sampled on
NEIGHBOUR_QUANTILES = (0.005, 0.995)  # the share of an exemplar's points with a nearer / farther nearest neighbour
# than the bounds of :meth:`Palette.neighbour_bounds_at_latent` (5 of its 1,024 points on each side)
DECODE_NEIGHBOURS = 8  # exemplars interpolated by a decode
DECODE_POWER = 4.0  # inverse-distance weight exponent of the decode (in PCF-code space)
# decoding compares PCFs coarse-grained to bins this wide (r_max), chosen leaving each exemplar of the shipped corpus
# out and decoding it from the others: median / p90 distance to its own colour 3.96 / 19.1 ab units (the 52 radii
# themselves 4.7 / 23.5, bins of 0.1 4.5 / 22.4, of 0.3 3.9 / 19.4; the layout's own CNN codes 1.9 / 13.7, but those
# are what the layout was built from, and a fresh realisation decodes further: docs/palette.md)
DECODE_BIN_WIDTH = 0.2
CLOSE_TO_CORPUS = 1.5  # nearest-exemplar distance (in exemplar spacings) up to which a decode is confident
OUTSIDE_CORPUS = 3.0  # nearest-exemplar distance (in exemplar spacings) beyond which a pattern is outside the corpus
# presets merged into another (fewer than 15 ab units apart in the shipped palette, lloyd-perturbed 3.6,
# step-jitter 6.7, so no colour could tell them apart); the old name still works, with a warning
MERGED_PRESETS = {"perturbed": "lloyd", "jitter": "step"}


def latent_to_ab(z: np.ndarray) -> np.ndarray:
    """Latent z in [0, 1] (..., 2) -> chroma (a, b) in [-128, 127]."""
    return 255.0 * np.asarray(z, np.float64) - 128.0


def ab_to_latent(ab: np.ndarray) -> np.ndarray:
    """Chroma (a, b) (..., 2) in [-128, 127] -> latent z in [0, 1]."""
    return (np.asarray(ab, np.float64) + 128.0) / 255.0


@dataclass(frozen=True)
class Decoded:
    """A decoded colour and how much to trust it.

    Attributes:
        a, b: chroma in [-128, 127].
        nearest_exemplar: index of the perceptually nearest corpus exemplar.
        exemplar_distance: feature distance to it, in units of the corpus's median
            distance between an exemplar and its nearest other exemplar (0 = an
            exemplar; about 1 = as close as the corpus's own neighbours).
    """

    a: float
    b: float
    nearest_exemplar: int
    exemplar_distance: float

    @property
    def confidence(self) -> str:
        """``"high"`` (within :data:`CLOSE_TO_CORPUS`), ``"low"`` or ``"outside the corpus"`` (beyond :data:`OUTSIDE_CORPUS`)."""
        if self.exemplar_distance <= CLOSE_TO_CORPUS:
            return "high"
        return "low" if self.exemplar_distance <= OUTSIDE_CORPUS else "outside the corpus"


def hue_chroma(a: float, b: float) -> tuple[float, float]:
    """CIELAB hue angle atan2(b, a) in degrees [0, 360) and chroma sqrt(a^2 + b^2)."""
    return float(np.degrees(np.arctan2(b, a)) % 360.0), float(np.hypot(a, b))


@dataclass(frozen=True, eq=False)
class Palette:
    """A loaded palette (arrays as stored in the asset; see :mod:`data_gen.palette`).

    Attributes:
        radii: (m,) PCF radii in units of r_max.
        lut: (256, 256, m) float32 PCFs; ``lut[i, j]`` is the PCF of a = i - 128, b = j - 128.
        exemplar_z: (N, 2) latent coordinates of the corpus exemplars.
        exemplar_pcf: (N, m) their PCFs.
        exemplar_points: (N, P, 2) their point sets on the unit torus.
        exemplar_spectrum: (N, B) the target radial power spectra they realise.
        exemplar_dispersion: (N, m) their count dispersion (:func:`synthesis.pcf.count_dispersion`).
        dispersion_lut: (64, 64, m) float32 IDW table of the dispersion, nodes at latent z = (i, j) / 63.
        codes: (N, k) PCA-reduced perceptual (CNN) features of the exemplars, those the layout was built from
            (decoding uses :attr:`pcf_codes` instead).
        feature_mean, components, block_scale: the feature reduction
            ``code = (features * block_weights - mean) @ components.T``.
        presets: name -> {"a", "b", ...}.
        extractor: description of the feature extractor that built the palette.
    """

    radii: np.ndarray
    lut: np.ndarray
    exemplar_z: np.ndarray
    exemplar_pcf: np.ndarray
    exemplar_points: np.ndarray
    exemplar_spectrum: np.ndarray
    exemplar_dispersion: np.ndarray
    dispersion_lut: np.ndarray
    codes: np.ndarray
    feature_mean: np.ndarray
    components: np.ndarray
    block_scale: np.ndarray
    presets: dict
    extractor: dict

    # --- I/O --------------------------------------------------------------
    @classmethod
    def load(cls, path: str | os.PathLike | None = None, layout_only: bool = False) -> Palette:
        """Load a palette asset (default: the shipped one).

        ``layout_only=True`` also reads format 2 (its PCF tables are in an older
        estimator's terms and it has no dispersion: ones stand in), for
        :mod:`data_gen.palette_table`, which rebuilds the tables from the layout.

        The arrays are read lazily: the file's bytes are read at once (so a later change to the file cannot mix
        two palettes), each array is decompressed and converted on its first use. Synthesis uses only ``radii``,
        ``lut``, ``dispersion_lut`` and the exemplars' positions with the bounds table beside the asset
        (:meth:`neighbour_bounds_at_latent`); the rest of the exemplars' tables and the feature reduction are for
        decoding, so a synthesis never pays for them.
        """
        path = Path(path) if path is not None else DEFAULT_PALETTE
        require_file(path, "a palette file", missing="palette not found (build it with 'python -m data_gen.palette')")
        try:
            data = np.load(io.BytesIO(path.read_bytes()), allow_pickle=False)
            version = int(data["format_version"])
            if version != FORMAT_VERSION and not (layout_only and version == 2):
                raise PatternshopError(f"{path}: palette format {version}, this Patternshop reads {FORMAT_VERSION}")
            missing = sorted(set(_STORED[version]) - set(data.files))
            if missing:
                raise KeyError(f"{', '.join(missing)} missing")
            palette = object.__new__(cls)
            object.__setattr__(palette, "_pending", _PendingArrays(path, data, version))
            object.__setattr__(palette, "presets", json.loads(str(data["presets_json"])))
            object.__setattr__(palette, "extractor", json.loads(str(data["extractor_json"])))
            return palette
        except _UNREADABLE as exc:
            raise PatternshopError(f"{path}: not a readable palette ({exc})") from exc

    def __getattr__(self, name: str) -> np.ndarray:
        """A lazily loaded array (:meth:`load`), converted on first use and kept."""
        pending = self.__dict__.get("_pending")
        if pending is None or name not in _CONVERTERS:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        value = pending.convert(name)
        object.__setattr__(self, name, value)
        return value

    def __getstate__(self) -> dict:
        """Pickle the arrays themselves (all of them loaded, the neighbour bounds table too), not the pending archive."""
        for name in (*_CONVERTERS, "exemplar_neighbour_bounds"):
            getattr(self, name)
        return {name: value for name, value in self.__dict__.items() if name != "_pending"}

    def save(self, path: str | os.PathLike) -> None:
        """Write the asset atomically (compressed npz; points as uint16, LUT and components as float16)."""
        from synthesis.atomic import atomic_path

        with atomic_path(path) as tmp:
            with open(tmp, "wb") as handle:
                np.savez_compressed(
                    handle,
                    format_version=np.int64(FORMAT_VERSION),
                    radii=self.radii.astype(np.float32),
                    lut=self.lut.astype(np.float16),
                    exemplar_z=self.exemplar_z.astype(np.float32),
                    exemplar_pcf=self.exemplar_pcf.astype(np.float32),
                    exemplar_points=np.rint(np.clip(self.exemplar_points, 0, 1) * 65535).astype(np.uint16),
                    exemplar_spectrum=self.exemplar_spectrum.astype(np.float32),
                    exemplar_dispersion=self.exemplar_dispersion.astype(np.float32),
                    dispersion_lut=self.dispersion_lut.astype(np.float16),
                    codes=self.codes.astype(np.float32),
                    feature_mean=self.feature_mean.astype(np.float32),
                    components=self.components.astype(np.float16),
                    block_scale=self.block_scale.astype(np.float32),
                    presets_json=np.str_(json.dumps(self.presets)),
                    extractor_json=np.str_(json.dumps(self.extractor)),
                )

    # --- encoding ---------------------------------------------------------
    def pcf_at_latent(self, z: np.ndarray) -> np.ndarray:
        """PCFs (..., m) for latent coordinates z (..., 2) in [0, 1], bilinear in the LUT."""
        return _bilinear(self._lookup_table("lut"), z)

    def dispersion_at_latent(self, z: np.ndarray) -> np.ndarray:
        """Count dispersions (..., m) for latent coordinates z (..., 2) in [0, 1], bilinear in their table."""
        return _bilinear(self._lookup_table("dispersion_lut"), z)

    def _lookup_table(self, name: str) -> np.ndarray:
        """Table ``name`` (``lut`` or ``dispersion_lut``) for :func:`_bilinear`: the float32 array once loaded, before
        that the stored float16 one, memory-mapped (:meth:`_PendingArrays.mapped`): the same samples (both convert to
        float64 exactly), and only the rows a map's colours need are read."""
        pending = self.__dict__.get("_pending")
        if name in self.__dict__ or pending is None or pending.version < FORMAT_VERSION:
            return getattr(self, name)
        return pending.mapped(name)

    def neighbour_bounds_at_latent(self, z: np.ndarray) -> np.ndarray:
        """(..., 2) float32 nearest-neighbour distances (r_max of the exemplar's count) that bound the target's own: the
        :data:`NEIGHBOUR_QUANTILES` of the NN distances of the exemplar nearest to each latent z (..., 2) in [0, 1] (a
        preset's exemplar is its generator). Read from the table shipped beside the asset (:func:`read_neighbour_table`);
        a palette without one (built in memory, or no table beside its file) measures each exemplar it needs on first
        use (:func:`exemplar_neighbour_bounds`, about 2 ms each) and keeps it.
        """
        flat = np.asarray(z, np.float64).reshape(-1, 2)
        exemplars = np.asarray(self.exemplar_z, np.float64)
        squares = np.sum(exemplars**2, axis=1)
        # squared distances up to each colour's own |z|^2, |e|^2 - 2 z.e: one product per 4,096 colours (~20 MB)
        nearest = np.concatenate([np.argmin(squares - 2.0 * flat[i:i + 4096] @ exemplars.T, axis=1)
                                  for i in range(0, len(flat), 4096)] + [np.zeros(0, np.int64)])
        bounds = self.exemplar_neighbour_bounds
        for index in np.unique(nearest[np.isnan(bounds[nearest, 0])]):
            bounds[index] = exemplar_neighbour_bounds(self.exemplar_points[index])
        return bounds[nearest].reshape(*np.shape(z)[:-1], 2)

    @functools.cached_property
    def exemplar_neighbour_bounds(self) -> np.ndarray:
        """(N, 2) float32 each exemplar's nearest-neighbour bounds (:meth:`neighbour_bounds_at_latent`): the table
        shipped beside the asset, or NaN for each exemplar not measured yet where there is none."""
        pending = self.__dict__.get("_pending")
        table = None if pending is None else read_neighbour_table(pending.path, pending.crc32("exemplar_points"))
        return table if table is not None else np.full((len(self.exemplar_z), 2), np.nan, np.float32)

    def pcf(self, a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
        """PCFs (..., m) for chroma a, b (scalars or arrays of one shape) in [-128, 127]."""
        return self.pcf_at_latent(ab_to_latent(np.stack(np.broadcast_arrays(a, b), axis=-1)))

    # --- decoding ---------------------------------------------------------
    @functools.cached_property
    def _extractor(self):  # noqa: ANN202 - FeatureExtractor, imported lazily (torch)
        from synthesis.features import FeatureExtractor

        return FeatureExtractor(self.extractor["name"], self.extractor.get("seed", 0), self.extractor.get("weights"))

    def reduce(self, features: np.ndarray) -> np.ndarray:
        """Raw CNN features (..., 61440) -> PCA codes (..., k) (the layout's, :attr:`codes`)."""
        from synthesis.features import scale_blocks

        scaled = scale_blocks(features, self.block_scale)
        return (scaled - self.feature_mean) @ self.components.T

    @functools.cached_property
    def pcf_codes(self) -> np.ndarray:
        """(N, k) the exemplars' decoding codes: :func:`pcf_code` of their PCFs."""
        return pcf_code(self.exemplar_pcf, self.radii)

    @functools.cached_property
    def exemplar_spacing(self) -> float:
        """Median distance between an exemplar's PCF code and its nearest other exemplar's (the unit of
        :attr:`Decoded.exemplar_distance`)."""
        from scipy.spatial import cKDTree

        distance, _ = cKDTree(self.pcf_codes).query(self.pcf_codes, k=2)
        return float(np.median(distance[:, 1]))

    def locate_code(self, code: np.ndarray, exclude: int | None = None) -> Decoded:
        """Decode a PCF code (k,) (:func:`pcf_code`): IDW of the nearest exemplars' latents (see the module docstring),
        exemplar ``exclude`` left out (a leave-one-out check)."""
        distance = np.sqrt(np.sum((self.pcf_codes - code) ** 2, axis=1))
        if exclude is not None:
            distance[exclude] = np.inf
        count = min(DECODE_NEIGHBOURS, len(distance))
        nearest = np.argpartition(distance, count - 1)[:count]
        nearest = nearest[np.argsort(distance[nearest])]
        weights = 1.0 / np.maximum(distance[nearest], 1e-9 * self.exemplar_spacing) ** DECODE_POWER
        a, b = latent_to_ab(weights @ self.exemplar_z[nearest] / weights.sum())
        return Decoded(float(a), float(b), int(nearest[0]), float(distance[nearest[0]] / self.exemplar_spacing))

    def locate_pcf(self, pcf: np.ndarray) -> Decoded:
        """Colour and confidence of a stationary pattern from its PCF (m,) at :attr:`radii`."""
        return self.locate_code(pcf_code(pcf, self.radii))

    def locate(self, points: np.ndarray, domain: tuple[float, float] = (1.0, 1.0), periodic: bool = False) -> Decoded:
        """Colour and confidence of a stationary pattern, points (n, 2) in [0, w] x [0, h], at any density and
        orientation (its PCF: :func:`synthesis.pcf.stationary_pcf`, minus sampling at the border unless ``periodic``).

        Raises:
            PatternshopError: too few points far enough from the border to measure a PCF.
        """
        from synthesis.pcf import stationary_pcf

        return self.locate_pcf(stationary_pcf(points, domain, periodic, radii=self.radii))

    def decode(self, points: np.ndarray, domain: tuple[float, float] = (1.0, 1.0), periodic: bool = False) -> tuple[float, float]:
        """Chroma (a, b) of a stationary pattern, points (n, 2) in [0, w] x [0, h], at any density (:meth:`locate`)."""
        decoded = self.locate(points, domain, periodic)
        return decoded.a, decoded.b

    # --- the populated region ----------------------------------------------
    @functools.cached_property
    def _populated_cells(self):  # noqa: ANN202 - (centres (k, 2), cKDTree), built lazily
        from scipy.spatial import cKDTree

        side = POPULATED_GRID
        centres = (np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), -1).reshape(-1, 2) + 0.5) / side
        distance, _ = cKDTree(self.exemplar_z).query(centres)
        centres = centres[distance <= POPULATED_RADIUS]
        return centres, cKDTree(centres)

    def is_populated(self, z: np.ndarray) -> np.ndarray:
        """(...) bool: latent z (..., 2) lies within :data:`POPULATED_RADIUS` of a corpus exemplar."""
        from scipy.spatial import cKDTree

        distance, _ = cKDTree(self.exemplar_z).query(np.asarray(z, np.float64).reshape(-1, 2))
        return (distance <= POPULATED_RADIUS).reshape(np.shape(z)[:-1])

    def snap_to_populated(self, z: np.ndarray) -> np.ndarray:
        """Latents z (..., 2) with each unpopulated one moved to the nearest populated grid cell centre."""
        z = np.asarray(z, np.float64)
        flat = z.reshape(-1, 2).copy()
        outside = ~self.is_populated(flat)
        if outside.any():
            centres, tree = self._populated_cells
            flat[outside] = centres[tree.query(flat[outside])[1]]
        return flat.reshape(z.shape)

    def sample_latents(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """(count, 2) latents uniform over the populated region (random cells of a 64 x 64 grid, jittered within)."""
        centres, _ = self._populated_cells
        z = centres[rng.integers(len(centres), size=count)] + (rng.random((count, 2)) - 0.5) / POPULATED_GRID
        return self.snap_to_populated(np.clip(z, 0.0, 1.0))

    # --- presets ----------------------------------------------------------
    def preset_ab(self) -> dict[str, tuple[float, float]]:
        """Preset name -> chroma (a, b), the merged names (:data:`MERGED_PRESETS`) left out."""
        return {name: (float(p["a"]), float(p["b"])) for name, p in self.presets.items() if name not in MERGED_PRESETS}

    def preset(self, name: str) -> tuple[float, float]:
        """The chroma (a, b) of preset ``name``; a merged name (:data:`MERGED_PRESETS`) warns and gives its successor's.

        Raises:
            PatternshopError: no preset of that name (the message lists them).
        """
        known = self.preset_ab()
        if name in MERGED_PRESETS and MERGED_PRESETS[name] in known:
            import warnings

            from synthesis.errors import PatternshopWarning

            old = self.presets[name]
            warnings.warn(f"preset {name!r} is merged into {MERGED_PRESETS[name]!r} (the palette cannot tell them apart); "
                          f"its former colour is --ab {old['a']:g} {old['b']:g}", PatternshopWarning, stacklevel=2)
            name = MERGED_PRESETS[name]
        if name not in known:
            raise PatternshopError(f"unknown preset {name!r}; presets: {', '.join(known)}")
        return known[name]

    def nearest_preset(self, a: float, b: float) -> str:
        """Name of the preset whose chroma is nearest to (a, b)."""
        return min(self.preset_ab().items(), key=lambda item: np.hypot(item[1][0] - a, item[1][1] - b))[0]


def exemplar_neighbour_bounds(points: np.ndarray) -> tuple[float, float]:
    """The :data:`NEIGHBOUR_QUANTILES` of the nearest-neighbour distances of points (P, 2) on the unit torus, in units of
    their r_max: one exemplar's bounds, measured (the reference of the shipped table, :func:`read_neighbour_table`)."""
    from scipy.spatial import cKDTree

    from synthesis.pcf import r_max

    wrapped = np.mod(np.asarray(points, np.float64), 1.0)  # cKDTree's periodic box takes coordinates in [0, 1)
    nearest = cKDTree(wrapped, boxsize=1.0).query(wrapped, k=2)[0][:, 1] / r_max(len(points))  # [:, 0]: itself
    low, high = np.quantile(nearest, NEIGHBOUR_QUANTILES)
    return float(low), float(high)


def neighbour_table_path(palette_path: str | os.PathLike) -> Path:
    """The nearest-neighbour bounds table shipped beside a palette asset: ``palette.npz`` -> ``palette_neighbours.npz``."""
    path = Path(palette_path)
    return path.with_name(path.stem + "_neighbours.npz")


def read_neighbour_table(palette_path: str | os.PathLike, points_crc32: int) -> np.ndarray | None:
    """(N, 2) float32 exemplar bounds from the table beside the palette at ``palette_path`` (written by
    ``python -m data_gen.palette_table --neighbours-only``, :func:`data_gen.palette_table.write_neighbour_table`),
    None if there is none. ``points_crc32``: the CRC-32 of the palette's stored ``exemplar_points``.

    Raises:
        PatternshopError: the table is unreadable or stale (built from other exemplar points or quantiles).
    """
    path = neighbour_table_path(palette_path)
    if not path.is_file():
        return None
    rebuild = "rebuild it with 'python -m data_gen.palette_table --neighbours-only'"
    try:
        with np.load(path, allow_pickle=False) as data:
            bounds, crc, quantiles = data["bounds"].astype(np.float32), int(data["points_crc32"]), data["quantiles"]
    except _UNREADABLE as exc:
        raise PatternshopError(f"{path}: not a readable neighbour bounds table ({exc}); {rebuild}") from exc
    if crc != points_crc32 or not np.array_equal(quantiles, NEIGHBOUR_QUANTILES) or bounds.ndim != 2 or bounds.shape[1] != 2:
        raise PatternshopError(f"{path}: stale neighbour bounds table (built for other exemplar points or quantiles than "
                               f"{Path(palette_path).name}'s); {rebuild}")
    return bounds


def pcf_code(pcf: np.ndarray, radii: np.ndarray, width: float = DECODE_BIN_WIDTH) -> np.ndarray:
    """Decoding code (..., k) of PCFs (..., m) at radii (m,) (r_max units): their area-weighted means over tent bins
    ``width`` wide centred on 0, width, 2 width, ... up to the last radius (a smoother PCF: fewer, less noisy values)."""
    radii = np.asarray(radii, np.float64)
    centres = np.arange(0.0, radii[-1] + 1e-9, width)
    area = np.maximum(radii, 0.5 * (radii[1] - radii[0]))  # a ring's area grows with r; r = 0 counts as half a bin
    tents = np.maximum(0.0, 1.0 - np.abs(radii[None, :] - centres[:, None]) / width) * area
    return np.asarray(pcf, np.float64) @ (tents / tents.sum(axis=1, keepdims=True)).T


def _bilinear(table: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Bilinear samples (..., m) of a (S, S, m) table whose nodes sit at latent (i, j) / (S - 1), at z (..., 2)."""
    size = table.shape[0]
    position = np.clip(np.asarray(z, np.float64), 0.0, 1.0) * (size - 1)
    lower = np.minimum(np.floor(position).astype(np.int64), size - 2)
    t = (position - lower)[..., None]
    i, j = lower[..., 0], lower[..., 1]
    ta, tb = t[..., 0, :], t[..., 1, :]
    return ((1 - ta) * (1 - tb) * table[i, j] + ta * (1 - tb) * table[i + 1, j]
            + (1 - ta) * tb * table[i, j + 1] + ta * tb * table[i + 1, j + 1]).astype(np.float32)


_UNREADABLE = (KeyError, ValueError, OSError, zipfile.BadZipFile, zlib.error)
# how each array is made from the stored ones (d: the archive, v: its format version)
_CONVERTERS: dict[str, Callable[[Mapping[str, np.ndarray], int], np.ndarray]] = {
    "radii": lambda d, v: d["radii"].astype(np.float64),
    "lut": lambda d, v: d["lut"].astype(np.float32),
    "exemplar_z": lambda d, v: d["exemplar_z"].astype(np.float64),
    "exemplar_pcf": lambda d, v: d["exemplar_pcf"].astype(np.float32),
    "exemplar_points": lambda d, v: d["exemplar_points"].astype(np.float64) / 65535.0,
    "exemplar_spectrum": lambda d, v: d["exemplar_spectrum"].astype(np.float64),
    "exemplar_dispersion": lambda d, v: (d["exemplar_dispersion"].astype(np.float32) if v >= 3
                                         else np.ones(d["exemplar_pcf"].shape, np.float32)),
    "dispersion_lut": lambda d, v: (d["dispersion_lut"].astype(np.float32) if v >= 3
                                    else np.ones((DISPERSION_LUT_SIZE, DISPERSION_LUT_SIZE, len(d["radii"])), np.float32)),
    "codes": lambda d, v: d["codes"].astype(np.float32),
    "feature_mean": lambda d, v: d["feature_mean"].astype(np.float32),
    "components": lambda d, v: d["components"].astype(np.float32),
    "block_scale": lambda d, v: d["block_scale"].astype(np.float32),
}
_COMMON = ("format_version", "radii", "lut", "exemplar_z", "exemplar_pcf", "exemplar_points", "exemplar_spectrum", "codes",
           "feature_mean", "components", "block_scale", "presets_json", "extractor_json")
_STORED = {2: _COMMON, FORMAT_VERSION: _COMMON + ("exemplar_dispersion", "dispersion_lut")}  # members a palette must have


class _PendingArrays:
    """The stored arrays of a :meth:`Palette.load` not yet used (an in-memory archive, decompressed member by member)."""

    def __init__(self, path: Path, data: Mapping[str, np.ndarray], version: int) -> None:
        self.path, self.data, self.version = path, data, version

    def convert(self, name: str) -> np.ndarray:
        try:
            return _CONVERTERS[name](self.data, self.version)
        except _UNREADABLE as exc:
            raise PatternshopError(f"{self.path}: not a readable palette ({exc})") from exc

    def crc32(self, name: str) -> int:
        """The stored CRC-32 of array ``name`` (the archive's directory: nothing is decompressed)."""
        return self.data.zip.getinfo(f"{name}.npy").CRC

    def mapped(self, name: str) -> np.ndarray:
        """Array ``name`` as stored, memory-mapped from a decompressed copy beside the asset
        (``__pycache__/STEM.NAME.CRC32.npy``, written on first use), else decompressed (a copy that cannot be read or
        written). Decompressing the 5 MB ``lut`` took 40 ms of every synthesis's start-up."""
        copy = self.path.parent / "__pycache__" / f"{self.path.stem}.{name}.{self.crc32(name):08x}.npy"
        with contextlib.suppress(OSError, ValueError):
            return np.load(copy, mmap_mode="r")
        try:
            array = self.data[name]
        except _UNREADABLE as exc:
            raise PatternshopError(f"{self.path}: not a readable palette ({exc})") from exc
        with contextlib.suppress(OSError):  # written whole, then renamed (another process may read it meanwhile)
            copy.parent.mkdir(exist_ok=True)
            handle, temporary = tempfile.mkstemp(suffix=".tmp", dir=copy.parent)
            try:
                with os.fdopen(handle, "wb") as out:
                    np.save(out, array)
                os.chmod(temporary, 0o644)  # readable by all, as the asset (mkstemp's file is the owner's only)
                os.replace(temporary, copy)
            finally:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(temporary)
            for stale in copy.parent.glob(glob.escape(f"{self.path.stem}.{name}.") + "[0-9a-f]" * 8 + ".npy"):
                if stale != copy:  # an earlier version's copy
                    stale.unlink()
        return array


@functools.lru_cache(maxsize=4)
def load_palette(path: str | None = None) -> Palette:
    """Cached :meth:`Palette.load` (one copy per process)."""
    return Palette.load(path)
