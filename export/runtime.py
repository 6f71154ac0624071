"""ONNX Runtime inference on the CPU: point sets in, maps out (no torch needed).

:class:`OnnxModel` wraps an exported generator (:mod:`patternshop_nn.onnx_export`);
:func:`points_to_map` turns a :class:`~synthesis.points.PointSet` into a
:class:`~synthesis.labmap.LabMap` with the function the network was trained on:

1. **Scale.** The network learnt density and correlation in pixel units: in
   training, a fully dark map held ``P_train`` points (the model's
   ``points_per_ink``, 8,000 for the default model) on a 256-pixel raster
   of the unit square. A pattern is read in the synthesiser's convention,
   ``points_per_ink`` per unit area of full ink, ``n = points_per_ink x w x h x
   mean density`` (:data:`synthesis.conventions.POINTS_PER_INK_MEANING`; default:
   the file's ``# points_per_ink`` header, else :func:`export.evidence.choose_points_per_ink`,
   so ``infer`` followed by ``synthesize`` keeps the point count), and rasterised at
   ``R = 256 * sqrt(points_per_ink / P_train)`` pixels per unit of the
   domain ``[0, w] x [0, h]``, so that a region of density d has as many points
   per pixel, at the same spacing in pixels, as in training.
2. **Mirror and pad.** The raster is :func:`synthesis.raster.point_raster`
   of the points and their mirror images across each side of the domain
   within ``border_px`` raster pixels (:class:`export.infer_config.InferConfig`),
   on a square canvas of side ``ceil((max(w, h) R + 2 border_px) / 64) * 64``
   (the U-Net needs multiples of 64): the domain's ``w R`` x ``h R`` pixels
   start at ``(border_px, border_px)``, the rest is empty. Without the mirror
   the network would see the pattern end at the domain's border and darken a
   rim there (it learnt the synthesiser's thinner borders).
3. **Run and crop back.** The network is fully convolutional; :func:`infer_map`
   averages its outputs over symmetries of the square (each flipped or
   transposed raster's output turned back; :func:`points_to_map`: one run);
   the output is cropped to the domain, decoded (L = 100 x channel 0, a, b = 255 x channels
   1-2 - 128) and resampled to the requested width (default: 256 px on the
   long side, the training maps' resolution).

:func:`infer_map` is what ``infer`` runs: the same reading, with the scale
chosen from the pattern's own local density unless given (:mod:`export.evidence`),
and the ink scaled so that the map holds the pattern's point count. Then:

* a model with an ``l_scale`` output (its predicted uncertainty of L) gets
  L smoothed within that uncertainty (:func:`smooth_reading`,
  :mod:`export.uncertainty`): one network pass per symmetry, nothing else;
* a model without it (v5 and earlier) gets :func:`read_v5_stages`: L
  sharpened from the points where they are regular and smoothed where its
  detail is no more than the noise of two Poisson resamplings of the map shows
  (:mod:`export.density`, :func:`refine_density`); the correlation of light
  areas read again at a zoom (as if the pattern held 2, 4 ... 64 times fewer
  points per ink, so the network sees them at a density it reads correlation
  at); and a, b filled from the surroundings where even then too few points
  show correlation.

Every constant of the first path is :class:`export.infer_config.InferConfig`'s.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path

from dataclasses import dataclass, replace

import numpy as np


from export.density import REGULAR_NOISE_SHARE, denoise_density, poisson_resample, sharpen_density
from export.evidence import (EvidenceSummary, ScaleChoice, blend_zoomed, calibrate_density, choose_points_per_ink, correlation_zoom,
                             fill_thin_correlation, local_evidence, summarise, zoom_levels)
from export.infer_config import DEFAULT_INFER, SYMMETRY_CHOICES, InferConfig
from export.uncertainty import smooth_by_uncertainty
from synthesis.conventions import full_ink_points
from synthesis.errors import PatternshopError, PatternshopWarning, require_file
from synthesis.labmap import AB_RANGE, L_RANGE, POINTS_PER_INK, LabMap, resample_channel
from synthesis.points import PointSet
from synthesis.raster import point_raster

DEFAULT_MODEL = Path(__file__).resolve().parent.parent / "patternshop_nn" / "assets" / "default.onnx"
INPUT_NAME = "raster"
OUTPUT_NAME = "map"
L_SCALE_NAME = "l_scale"  # the optional second output: (B, 1, H, W) predicted Laplace scale of the density (0..1)
SIZE_MULTIPLE = 64  # raster sides must be multiples of 2**levels of the U-Net (6 levels)
# Models without l_scale (v5 and earlier) only; these go with read_v5_stages:
BOOTSTRAP_SEED = 0  # the Poisson resamplings of :func:`bootstrap_noise` (infer is deterministic)
V5_SYMMETRIES = 8  # infer's readings per map for them: the model card's figures were measured at 8 (4 overstates the noise)

PathLike = str | os.PathLike


class OnnxModel:
    """An exported Patternshop generator in an ONNX Runtime CPU session.

    Args:
        path: ``.onnx`` file (default: :data:`DEFAULT_MODEL`).
        threads: ONNX Runtime intra-op threads (default 1).

    Attributes:
        path: the model file.
        metadata: the model's metadata (see :mod:`patternshop_nn.onnx_export`), values JSON-decoded.
        raster_size: the training rasters' side (256); :meth:`predict` takes any multiple of 64.
        threads: ONNX Runtime intra-op threads.
        has_l_scale: the model predicts the Laplace scale of its density (output ``l_scale``): ``infer`` then
            smooths L by it (:func:`export.uncertainty.smooth_by_uncertainty`) instead of :func:`read_v5_stages`.

    Raises:
        PatternshopError: the file is missing, unreadable, or not a Patternshop model.
    """

    def __init__(self, path: PathLike | None = None, threads: int = 1) -> None:
        if path is None and not DEFAULT_MODEL.is_file():
            raise PatternshopError(f"no default model at {DEFAULT_MODEL}; train one with 'python train.py' and export it "
                                   f"with 'patternshop export runs/procedural/checkpoints/best.ckpt {DEFAULT_MODEL}', or pass --model")
        self.path = Path(path) if path is not None else DEFAULT_MODEL
        self.threads = threads
        require_file(self.path, "an ONNX model file", missing="no such model file")
        if threads < 1:
            raise PatternshopError(f"threads must be at least 1, got {threads}")
        import onnxruntime  # here, not at the top: convert's rasterising workers import this module without it

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        try:
            self.session = onnxruntime.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime's own classes (InvalidProtobuf, InvalidArgument, Fail ...) derive from Exception
            reason = str(exc).rsplit("failed:", 1)[-1].strip()
            raise PatternshopError(f"{self.path}: not a readable ONNX model ({reason})") from exc
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        shape = inputs[0].shape if len(inputs) == 1 else []
        output_names = [o.name for o in outputs]
        if [i.name for i in inputs] != [INPUT_NAME] or output_names not in ([OUTPUT_NAME], [OUTPUT_NAME, L_SCALE_NAME]) \
                or len(shape) != 4 or shape[1] != 1:
            raise PatternshopError(f"{self.path}: not a Patternshop model (needs input '{INPUT_NAME}' (B, 1, H, W) "
                                   f"and output '{OUTPUT_NAME}', optionally '{L_SCALE_NAME}')")
        self.has_l_scale = L_SCALE_NAME in output_names
        self.metadata = {key: _decode(value) for key, value in self.session.get_modelmeta().custom_metadata_map.items()}
        if "patternshop_format" not in self.metadata:
            raise PatternshopError(f"{self.path}: not a Patternshop model (no patternshop_format in its metadata; "
                                   "export one with 'patternshop export')")
        self.raster_size = int(self.metadata.get("raster_size", 256))

    @property
    def points_per_ink(self) -> float | None:
        """Points of a fully dark unit square in the training data, when the model records it."""
        value = self.metadata.get("points_per_ink")
        return float(value) if value is not None else None

    def predict(self, rasters: np.ndarray) -> np.ndarray:
        """Maps (B, 3, H, W) float32 in [0, 1] (L/100, z_a, z_b) for rasters (B, 1, H, W) in [0, 1], H, W multiples of 64."""
        return self.session.run([OUTPUT_NAME], {INPUT_NAME: _checked(rasters)})[0]

    def predict_outputs(self, rasters: np.ndarray) -> np.ndarray:
        """(B, C, H, W) float32: the map's 3 channels (:meth:`predict`), then with :attr:`has_l_scale` the
        predicted Laplace scale of the density (C = 4), for rasters (B, 1, H, W); one network pass."""
        names = [OUTPUT_NAME, L_SCALE_NAME] if self.has_l_scale else [OUTPUT_NAME]
        return np.concatenate(self.session.run(names, {INPUT_NAME: _checked(rasters)}), axis=1)

    def __repr__(self) -> str:
        return f"OnnxModel({self.path}, {self.raster_size} px)"


def _checked(rasters: np.ndarray) -> np.ndarray:
    """Rasters as float32 (B, 1, H, W), H and W multiples of :data:`SIZE_MULTIPLE` (ValueError otherwise)."""
    rasters = np.ascontiguousarray(rasters, dtype=np.float32)
    if rasters.ndim != 4 or rasters.shape[1] != 1 or rasters.shape[2] % SIZE_MULTIPLE or rasters.shape[3] % SIZE_MULTIPLE:
        raise ValueError(f"rasters must have shape (B, 1, H, W) with H, W multiples of {SIZE_MULTIPLE}, got {rasters.shape}")
    return rasters


def _decode(value: str) -> object:
    """A metadata value: JSON as the exporter writes it, else the plain string (models from elsewhere)."""
    try:
        return json.loads(value)
    except json.JSONDecodeError:
        return value


def mirrored(points: PointSet, margin: float) -> np.ndarray:
    """(m, 2) the points and their mirror images across each side of the domain within ``margin`` of it (corners too)."""
    w, h = points.domain
    xy = points.xy
    copies = [xy]
    for axis, side in ((0, w), (1, h)):
        layer = np.concatenate(copies)
        near_low, near_high = layer[layer[:, axis] < margin], layer[layer[:, axis] > side - margin]
        low, high = near_low.copy(), near_high.copy()
        low[:, axis] = -low[:, axis]
        high[:, axis] = 2.0 * side - high[:, axis]
        copies = [layer, low, high]
    return np.concatenate(copies)


def pattern_raster(points: PointSet, raster_size: int, trained_points_per_ink: float | None,
                   points_per_ink: float = POINTS_PER_INK, border_px: int = DEFAULT_INFER.border_px) -> tuple[np.ndarray, float]:
    """(raster (S, S) float32 in [0, 1], pixels per unit R) of a pattern, mirrored at its border and padded (steps 1-2).

    ``raster_size`` and ``trained_points_per_ink`` are the model's (:class:`OnnxModel`); a model that does not
    record its points per ink is taken to share the pattern's (R = raster_size). The domain's pixels start at
    (``border_px``, ``border_px``) (:attr:`export.infer_config.InferConfig.border_px`).
    """
    scale, side = raster_scale(points.domain, raster_size, trained_points_per_ink, points_per_ink, border_px)
    margin = border_px / scale
    return point_raster((mirrored(points, margin) + margin) * (scale / side), side), scale


def raster_scale(domain: tuple[float, float], raster_size: int, trained_points_per_ink: float | None,
                 points_per_ink: float = POINTS_PER_INK, border_px: int = DEFAULT_INFER.border_px) -> tuple[float, int]:
    """(pixels per unit R, raster side S in pixels, a multiple of 64 holding the domain and its mirrored border)."""
    if not points_per_ink > 0:
        raise PatternshopError(f"points per ink must be positive, got {points_per_ink:g}")
    w, h = domain
    scale = raster_size * math.sqrt(points_per_ink / (trained_points_per_ink or points_per_ink))
    return scale, SIZE_MULTIPLE * max(1, math.ceil((scale * max(w, h) + 2 * border_px) / SIZE_MULTIPLE - 1e-9))


def output_to_map(output: np.ndarray, domain: tuple[float, float], scale: float, width: int,
                  border_px: int = DEFAULT_INFER.border_px) -> LabMap:
    """Decode one network output (3, S, S) in [0, 1]: crop to the domain's ``w R`` x ``h R`` pixels, resample to ``width``."""
    output = domain_crop(output, domain, scale, border_px)
    return network_map(output, (max(1, round(width * output.shape[1] / output.shape[2])), width))


def network_map(output: np.ndarray, shape: tuple[int, int]) -> LabMap:
    """The map of a network output (3, h, w) in [0, 1] resampled to ``shape`` (H, W): the values of
    ``resample_map(LabMap.from_network(output), shape)``, decoded plane by plane without the (h, w, 3) map between
    (4-5 ms instead of 9-13 ms from 586 to 256 px, ``tests/test_convert_edit.py::test_network_map_is_the_plain_decoding``)."""
    output = np.asarray(output, np.float32)
    planes = [np.clip(100.0 * (1.0 - (1.0 - output[0])), *L_RANGE)]  # LabMap.from_density_latent's arithmetic, in float32
    planes += [np.clip(255.0 * output[c] - 128.0, *AB_RANGE) for c in (1, 2)]
    return LabMap(np.stack([resample_channel(plane, shape) for plane in planes], axis=-1))


def domain_crop(output: np.ndarray, domain: tuple[float, float], scale: float,
                border_px: int = DEFAULT_INFER.border_px) -> np.ndarray:
    """(C, hR, wR) the part of a network output (C, S, S) over the domain (from ``border_px`` on)."""
    w, h = domain
    return np.asarray(output, np.float32)[:, border_px : border_px + max(1, round(h * scale)), border_px : border_px + max(1, round(w * scale))]


def map_width(domain: tuple[float, float], model: OnnxModel, width: int | None) -> int:
    """Output width: ``width``, or the training maps' resolution (raster_size px on the long side)."""
    return width if width is not None else max(1, round(domain[0] / max(domain) * model.raster_size))


def saturation_warning(count: int, points_per_ink: float, domain: tuple[float, float]) -> str | None:
    """A warning when ``count`` points exceed a fully dark map of ``domain`` at ``points_per_ink`` (mean density > 1), else None."""
    if count <= full_ink_points(points_per_ink, domain):
        return None
    return (f"{count} points are more than a fully dark map holds at {points_per_ink:g} points per ink: the map "
            "comes out saturated (L near 0); pass a larger --points-per-ink")


def points_to_map(points: PointSet, model: OnnxModel, width: int | None = None,
                  points_per_ink: float = POINTS_PER_INK) -> LabMap:
    """The network's map of a point set read at ``points_per_ink`` (see the module docstring), L and a, b as it gave them.

    ``width`` in pixels (default: 256 on the long side); ``points_per_ink``: points of a fully dark map in the
    pattern's own scale (the synthesiser's convention). Warns (:class:`PatternshopWarning`) when the pattern
    holds more points than that.
    """
    return infer_map(points, model, width, ScaleChoice(points_per_ink, False), fill_thin=False, calibrate=False,
                     symmetries=1).lab_map


@dataclass(frozen=True)
class Inference:
    """What :func:`infer_map` made: the map, the scale it read the pattern at, and the correlation evidence.

    ``output`` is the network's raw output over the domain (3, hR, wR) in [0, 1] of the main reading,
    ``pixels_per_unit`` its raster's pixels per unit of the domain (R). ``evidence`` summarises where too few
    points show correlation (None for a model with ``l_scale``, which reads thin areas itself). ``zooms`` are the
    readings made for correlation (1: the main one only), ``zoomed_share``
    the share of the map whose a, b came from a zoomed reading, ``calibration`` the ink factor applied
    (None: the network's L as it came), ``symmetries`` how many symmetries each reading averaged,
    ``sharpened_share`` the share of L taken from the points rather than the network, ``denoised_px`` the
    mean width (px) of the smoothing L took where its detail was noise (:mod:`export.density`) or within its
    predicted uncertainty (:mod:`export.uncertainty`); ``l_scale`` (H, W) that prediction, the Laplace scale of
    the map's density in density units (times the ink factor), None for a model without it.
    """

    lab_map: LabMap
    scale: ScaleChoice
    evidence: EvidenceSummary | None
    output: np.ndarray
    pixels_per_unit: float
    zooms: tuple[int, ...] = (1,)
    zoomed_share: float = 0.0
    calibration: float | None = None
    symmetries: int = 1
    sharpened_share: float = 0.0
    denoised_px: float = 0.0
    l_scale: np.ndarray | None = None

    def report(self) -> dict:
        return {"width": self.lab_map.width, "height": self.lab_map.height, "symmetries": self.symmetries,
                **self.scale.report(), **(self.evidence.report() if self.evidence is not None else {}),
                "correlation_zooms": list(self.zooms), "zoomed_share": round(self.zoomed_share, 4),
                "ink_calibration_factor": None if self.calibration is None else round(self.calibration, 4),
                "sharpened_share": round(self.sharpened_share, 4), "denoised_px": round(self.denoised_px, 3),
                "l_scale_mean": None if self.l_scale is None else round(float(self.l_scale.mean()), 5)}


def dihedral(array: np.ndarray, code: int, inverse: bool = False) -> np.ndarray:
    """One of the 8 symmetries of the square on the last two axes of ``array`` (..., S, S): bit 0 of ``code``
    flips x, bit 1 flips y, bit 2 transposes (in that order; ``inverse`` undoes it)."""
    if inverse and code & 4:
        array = np.swapaxes(array, -1, -2)
    if code & 1:
        array = array[..., ::-1]
    if code & 2:
        array = array[..., ::-1, :]
    if not inverse and code & 4:
        array = np.swapaxes(array, -1, -2)
    return array


def predict_symmetric(model: OnnxModel, raster: np.ndarray, symmetries: int) -> np.ndarray:
    """(C, S, S) the network's outputs (:meth:`OnnxModel.predict_outputs`) for a raster (S, S), averaged over
    ``symmetries`` (:data:`export.infer_config.SYMMETRY_CHOICES`) symmetries of the square, codes 0 ..
    ``symmetries - 1`` of :func:`dihedral`: each transformed raster's output transformed back. The network was
    trained on all 8 (``data.augment``); averaging cancels what of its response is not symmetric (noise read as
    structure). One raster per run, so memory stays that of one reading."""
    if symmetries not in SYMMETRY_CHOICES:
        raise PatternshopError(f"symmetries must be one of {', '.join(map(str, SYMMETRY_CHOICES))}, got {symmetries}")
    total = None
    for code in range(symmetries):
        output = dihedral(model.predict_outputs(np.ascontiguousarray(dihedral(raster, code))[None, None])[0], code, inverse=True)
        total = np.array(output, np.float32) if total is None else np.add(total, output, out=total)
    return total if symmetries == 1 else total / np.float32(symmetries)


def read_pattern(points: PointSet, model: OnnxModel, points_per_ink: float, shape: tuple[int, int], symmetries: int,
                 border_px: int = DEFAULT_INFER.border_px) -> tuple[LabMap, np.ndarray, float, np.ndarray | None]:
    """(map resampled to ``shape`` (H, W), raw map output over the domain (3, hR, wR), pixels per unit R, the
    predicted Laplace scale of the density resampled to ``shape`` (H, W), None without ``l_scale``): one reading,
    averaged over ``symmetries`` (:func:`predict_symmetric`)."""
    raster, pixels_per_unit = pattern_raster(points, model.raster_size, model.points_per_ink, points_per_ink, border_px)
    output = domain_crop(predict_symmetric(model, raster, symmetries), points.domain, pixels_per_unit, border_px)
    lab_map = network_map(output[:3], shape)
    l_scale = resample_channel(output[3], shape).astype(np.float64) if len(output) > 3 else None
    return lab_map, output[:3], pixels_per_unit, l_scale


def with_density(lab_map: LabMap, density: np.ndarray) -> LabMap:
    """The map with L from ``density`` (H, W) in [0, 1] and its own a, b."""
    return LabMap(np.concatenate([100.0 * (1.0 - density[..., None]), lab_map.ab.astype(np.float64)], axis=-1))


def smooth_reading(reading: Inference, density: np.ndarray, l_scale: np.ndarray, ink: float, smooth: bool,
                   config: InferConfig = DEFAULT_INFER) -> Inference:
    """A model with ``l_scale``: the reading's ``density`` (H, W) in [0, 1] (calibrated) smoothed within its predicted
    Laplace scale ``l_scale`` (H, W) times the ink factor (:func:`export.uncertainty.smooth_by_uncertainty`), then
    water-filled back to ``ink`` (mean density); ``smooth`` False (or no points) keeps it."""
    l_scale = l_scale * (reading.calibration if reading.calibration is not None else 1.0)
    if not smooth or ink <= 0:
        return replace(reading, l_scale=l_scale)
    smoothed, width = smooth_by_uncertainty(density, l_scale, config)
    smoothed, _ = calibrate_density(smoothed, ink)
    return replace(reading, lab_map=with_density(reading.lab_map, smoothed), denoised_px=float(width.mean()), l_scale=l_scale)


# --- models without l_scale (v5 and earlier): zoomed correlation, thin fill, sharpening, bootstrap denoising ----------
def bootstrap_noise(points: PointSet, model: OnnxModel, density: np.ndarray, points_per_ink: float, symmetries: int,
                    config: InferConfig = DEFAULT_INFER) -> np.ndarray:
    """(H, W) a sample of the noise in the network's calibrated density of a pattern, its ``density`` (H, W)
    in [0, 1] at ``points_per_ink``: the difference of two readings of Poisson resamplings of that density
    (:func:`export.density.poisson_resample`, seed :data:`BOOTSTRAP_SEED`), over sqrt(2). A parametric
    bootstrap: it holds the noise a Poisson pattern of this density shows through the network, with its
    amplitude and its grain."""
    shape = density.shape
    px_per_unit = shape[1] / points.domain[0]
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    readings = []
    for _ in range(2):
        xy = poisson_resample(density, full_ink_points(points_per_ink, points.domain) / density.size, rng) / px_per_unit
        resampled = PointSet(np.minimum(xy, np.asarray(points.domain)), points.domain)
        lab_map = read_pattern(resampled, model, points_per_ink, shape, symmetries, config.border_px)[0]
        readings.append(calibrate_density(lab_map.density(), len(resampled) / full_ink_points(points_per_ink, points.domain))[0])
    return (readings[0] - readings[1]) / math.sqrt(2.0)


def refine_density(points: PointSet, model: OnnxModel, density: np.ndarray, points_per_ink: float, sharpen: bool,
                   denoise: bool, symmetries: int, config: InferConfig = DEFAULT_INFER) -> tuple[np.ndarray, float, float]:
    """(density (H, W), share sharpened, mean smoothing width in px) of the network's calibrated ``density``
    (H, W) in [0, 1] of ``points`` at ``points_per_ink``, with the ink restored.

    ``denoise``: the network's density is smoothed where its detail is what a Poisson pattern's noise
    would give (:func:`export.density.denoise_density`, the noise from :func:`bootstrap_noise`).
    ``sharpen``: then taken from the points where they are regular
    (:func:`export.density.sharpen_density`), and that part smoothed where its detail is what
    :data:`export.density.REGULAR_NOISE_SHARE` of that noise would give.
    """
    ink = len(points) / full_ink_points(points_per_ink, points.domain)
    refined, width, weight = density, np.zeros(density.shape), np.zeros(density.shape)
    if denoise:
        noise = bootstrap_noise(points, model, density, points_per_ink, symmetries, config)
        refined, width = denoise_density(refined, noise, config=config)
    if sharpen:
        refined, weight = sharpen_density(points, refined, points_per_ink)
        if denoise:
            refined, _ = calibrate_density(refined, ink)
            refined, regular_width = denoise_density(refined, noise, REGULAR_NOISE_SHARE * weight, config)
            width = np.hypot(width, regular_width)  # two Gaussian smoothings in a row: widths add in quadrature
    refined, _ = calibrate_density(refined, ink)
    return refined, float(weight.mean()), float(width.mean())


def read_v5_stages(points: PointSet, model: OnnxModel, reading: Inference, density: np.ndarray, fill_thin: bool,
                   sharpen: bool, denoise: bool, config: InferConfig = DEFAULT_INFER) -> Inference:
    """A model without ``l_scale``: the reading (its ``density`` (H, W) in [0, 1], calibrated when
    ``reading.calibration`` is set) finished as ``infer`` did for v5 (see :func:`infer_map`'s arguments):
    light areas' a, b from zoomed readings and thin a, b filled (:mod:`export.evidence`), L sharpened and
    denoised (:func:`refine_density`). Deleted with the last such model, with :func:`refine_density`,
    :func:`bootstrap_noise` and the stages they call."""
    shape, scale, symmetries = density.shape, reading.scale, reading.symmetries
    ab = reading.lab_map.ab.astype(np.float64)
    evidence = local_evidence(points, shape, reading.pixels_per_unit)
    zooms, zoomed_share = (1,), 0.0
    if fill_thin and len(points):
        zoom = correlation_zoom(density)
        zooms = zoom_levels(zoom)
        ab_readings, evidence_readings = [ab], [evidence]
        for f in zooms[1:]:
            zoomed, _, zoomed_pixels_per_unit, _ = read_pattern(points, model, scale.points_per_ink / f, shape, symmetries,
                                                                config.border_px)
            ab_readings.append(zoomed.ab.astype(np.float64))
            evidence_readings.append(local_evidence(points, shape, zoomed_pixels_per_unit))
        ab, evidence = blend_zoomed(zoom, zooms, ab_readings), blend_zoomed(zoom, zooms, evidence_readings)
        zoomed_share = float(np.mean(zoom > 1.0)) if len(zooms) > 1 else 0.0
    lab_map = LabMap(np.concatenate([100.0 * (1.0 - density[..., None]), ab], axis=-1))
    source = False
    if fill_thin:
        lab_map, source = fill_thin_correlation(lab_map, evidence)
    sharpened_share = denoised_px = 0.0
    if reading.calibration is not None and (sharpen or denoise) and len(points):  # L only: the zoom and the fill read the network's density
        refined, sharpened_share, denoised_px = refine_density(points, model, density, scale.points_per_ink, sharpen,
                                                               denoise, symmetries, config)
        lab_map = with_density(lab_map, refined)
    return replace(reading, lab_map=lab_map, evidence=summarise(evidence, fill_thin and source, source), zooms=zooms,
                   zoomed_share=zoomed_share, sharpened_share=sharpened_share, denoised_px=denoised_px)


def infer_map(points: PointSet, model: OnnxModel, width: int | None = None, scale: ScaleChoice | None = None,
              fill_thin: bool = True, calibrate: bool = True, symmetries: int | None = None,
              sharpen: bool = True, denoise: bool = True, config: InferConfig = DEFAULT_INFER) -> Inference:
    """Infer the map of a point set as ``infer`` does (see the module docstring and :mod:`export.evidence`).

    Args:
        points: the pattern.
        model: the network.
        width: map width in pixels (default: 256 on the long side).
        scale: the pattern's scale; None chooses it (:func:`export.evidence.choose_points_per_ink`, the
            default :data:`POINTS_PER_INK` unless the pattern is denser). A given scale warns
            (:class:`PatternshopWarning`) when the pattern holds more points than a fully dark map.
        fill_thin: (models without ``l_scale``) read a, b of light areas at a zoom
            (:func:`export.evidence.correlation_zoom`) and replace them where the evidence stays thin by the
            surrounding well-observed a, b.
        calibrate: scale the ink to the pattern's point count (:func:`export.evidence.calibrate_density`);
            False keeps the network's L.
        sharpen: (models without ``l_scale``) with ``calibrate``, take L from the points where they are regular
            (:func:`export.density.sharpen_density`), then restore the ink; a, b are read as without it.
        denoise: with ``calibrate``, smooth L: within its predicted uncertainty (:func:`smooth_reading`), or,
            for a model without ``l_scale``, where its detail is what the pattern's own noise explains
            (:func:`refine_density`); a, b are read as without it.
        symmetries: readings averaged over this many symmetries of the square (:func:`predict_symmetric`);
            None: ``config.symmetries`` for a model with ``l_scale``, :data:`V5_SYMMETRIES` for one without.
        config: the constants around the network (:class:`export.infer_config.InferConfig`).

    Raises:
        PatternshopError: a degenerate pattern, most points on top of each other
            (:func:`synthesis.analysis.check_not_degenerate`, as ``analyze`` refuses it).
    """
    from synthesis.analysis import check_not_degenerate

    check_not_degenerate(points)
    scale = scale if scale is not None else choose_points_per_ink(points, POINTS_PER_INK, config)
    if not scale.automatic:
        message = saturation_warning(len(points), scale.points_per_ink, points.domain)
        if message:
            warnings.warn(message, PatternshopWarning, stacklevel=2)
    if symmetries is None:
        symmetries = config.symmetries if model.has_l_scale else V5_SYMMETRIES
    width_px = map_width(points.domain, model, width)
    shape = (max(1, round(width_px * points.domain[1] / points.domain[0])), width_px)
    lab_map, output, pixels_per_unit, l_scale = read_pattern(points, model, scale.points_per_ink, shape, symmetries,
                                                             config.border_px)
    density, factor = lab_map.density().astype(np.float64), None
    ink = len(points) / full_ink_points(scale.points_per_ink, points.domain)
    if calibrate:
        density, factor = calibrate_density(density, ink)
    reading = Inference(with_density(lab_map, density), scale, None, output, pixels_per_unit, calibration=factor,
                        symmetries=symmetries)
    if l_scale is None:
        return read_v5_stages(points, model, reading, density, fill_thin, sharpen, denoise, config)
    return smooth_reading(reading, density, l_scale, ink, calibrate and denoise, config)


def check_palette(model: OnnxModel, palette_file: PathLike | None = None) -> None:
    """Warn when the model's a, b refer to another palette than ``palette_file`` (default: the shipped one)."""
    from data_gen.provenance import file_sha256
    from synthesis.palette import DEFAULT_PALETTE

    recorded = model.metadata.get("palette_sha256")
    palette_file = Path(palette_file) if palette_file is not None else DEFAULT_PALETTE
    if recorded and palette_file.is_file() and recorded != file_sha256(palette_file):
        warnings.warn(f"{model.path} was trained with another palette than {palette_file} (sha256 {str(recorded)[:12]}...): "
                      "its colours may stand for other correlations", PatternshopWarning, stacklevel=2)
