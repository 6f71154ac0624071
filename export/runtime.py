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
   on a square canvas of side ``ceil((max(w, h) R + 2 border_px) / 64) * 64``
   (the U-Net needs multiples of 64): the domain's ``w R`` x ``h R`` pixels
   start at ``(border_px, border_px)`` (:class:`export.infer_config.InferConfig`),
   and its mirror images fill the canvas around it, ``border_px`` before the
   domain and the rest of the canvas after it. Without the mirror the network
   would see the pattern end at the domain's border and darken a rim there (it
   learnt the synthesiser's thinner borders); with an empty band beyond it, it
   reads a density edge there and turns the last pixels of the map to grain.
3. **Run and crop back.** The network is fully convolutional; :func:`infer_map`
   averages its outputs over symmetries of the square (each flipped or
   transposed raster's output turned back; :func:`points_to_map`: one run);
   the output is cropped to the domain, decoded (L = 100 x channel 0, a, b = 255 x channels
   1-2 - 128) and resampled to the requested width (default: 256 px on the
   long side, the training maps' resolution).

:func:`infer_map` is what ``infer`` runs: the same reading, with the scale
chosen from the pattern's own local density unless given (:mod:`export.evidence`),
and the ink scaled so that the map holds the pattern's point count: one network
pass per symmetry. A model with an ``l_scale`` output (its predicted uncertainty
of L) then gets L smoothed within that uncertainty (:func:`smooth_reading`,
:mod:`export.uncertainty`); a model without it (older exports, models trained
with ``l_scale=false``) gets nothing more: its L is not smoothed.

Every constant of this path is :class:`export.infer_config.InferConfig`'s.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path

from dataclasses import dataclass, replace

import numpy as np


from export.evidence import ScaleChoice, calibrate_density, choose_points_per_ink
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
            smooths L by it (:func:`export.uncertainty.smooth_by_uncertainty`); without it L is not smoothed.

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
        predicted Laplace scale of the density (C = 4), for rasters (B, 1, H, W); one network pass. A new array
        each call: callers may write into it (:func:`predict_symmetric` sums into the first)."""
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


def mirrored(points: PointSet, margin: float, far: tuple[float, float] | None = None) -> np.ndarray:
    """(m, 2) the points and their images in the domain's mirror extension (reflections across its sides, repeated)
    that lie within ``margin`` beyond its low sides (x, y < 0) and ``far`` = (x, y) beyond its high sides (default
    ``margin``; corners too). Units of the domain; an image lies strictly inside that band, the points themselves stay."""
    far = (margin, margin) if far is None else far
    layer = points.xy
    for axis, side, reach in ((0, points.domain[0], far[0]), (1, points.domain[1], far[1])):
        images = [layer]
        for period in range(-math.ceil(margin / (2 * side)) - 1, math.ceil((side + reach) / (2 * side)) + 1):
            for sign in (1.0, -1.0):
                if period == 0 and sign == 1.0:
                    continue
                coordinate = 2.0 * period * side + sign * layer[:, axis]
                inside = (coordinate > -margin) & (coordinate < side + reach)
                image = layer[inside]  # a copy
                image[:, axis] = coordinate[inside]
                images.append(image)
        layer = np.concatenate(images)
    return layer


def pattern_raster(points: PointSet, raster_size: int, trained_points_per_ink: float | None,
                   points_per_ink: float = POINTS_PER_INK, border_px: int = DEFAULT_INFER.border_px) -> tuple[np.ndarray, float]:
    """(raster (S, S) float32 in [0, 1], pixels per unit R) of a pattern, mirrored at its border and padded (steps 1-2).

    ``raster_size`` and ``trained_points_per_ink`` are the model's (:class:`OnnxModel`); a model that does not
    record its points per ink is taken to share the pattern's (R = raster_size). The domain's pixels start at
    (``border_px``, ``border_px``) (:attr:`export.infer_config.InferConfig.border_px`).
    """
    scale, side = raster_scale(points.domain, raster_size, trained_points_per_ink, points_per_ink, border_px)
    margin = border_px / scale
    reach = side / scale - margin  # from the domain's origin to the canvas's far sides, in domain units
    far = (reach - points.domain[0], reach - points.domain[1])
    return point_raster((mirrored(points, margin, far) + margin) * (scale / side), side), scale


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
    return infer_map(points, model, width, ScaleChoice(points_per_ink, False), calibrate=False, symmetries=1).lab_map


@dataclass(frozen=True)
class Inference:
    """What :func:`infer_map` made: the map and the scale it read the pattern at.

    ``output`` is the network's raw output over the domain (3, hR, wR) in [0, 1] of the reading,
    ``pixels_per_unit`` its raster's pixels per unit of the domain (R), ``calibration`` the ink factor applied
    (None: the network's L as it came), ``symmetries`` how many symmetries the reading averaged, ``denoised_px``
    the mean width (px) of the smoothing L took within its predicted uncertainty (:mod:`export.uncertainty`; 0
    for a model without ``l_scale``); ``l_scale`` (H, W) that prediction, the Laplace scale of the map's density
    in density units (times the ink factor), None for a model without it.
    """

    lab_map: LabMap
    scale: ScaleChoice
    output: np.ndarray
    pixels_per_unit: float
    calibration: float | None = None
    symmetries: int = 1
    denoised_px: float = 0.0
    l_scale: np.ndarray | None = None

    def report(self) -> dict:
        return {"width": self.lab_map.width, "height": self.lab_map.height, "symmetries": self.symmetries,
                **self.scale.report(),
                "ink_calibration_factor": None if self.calibration is None else round(self.calibration, 4),
                "denoised_px": round(self.denoised_px, 3),
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
        # the first reading is a fresh array of this call's own: summed into in place, not copied (3 ms on 704 px)
        total = np.asarray(output, np.float32) if total is None else np.add(total, output, out=total)
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


def infer_map(points: PointSet, model: OnnxModel, width: int | None = None, scale: ScaleChoice | None = None,
              calibrate: bool = True, symmetries: int | None = None, denoise: bool = True,
              config: InferConfig = DEFAULT_INFER) -> Inference:
    """Infer the map of a point set as ``infer`` does (see the module docstring and :mod:`export.evidence`).

    Args:
        points: the pattern.
        model: the network.
        width: map width in pixels (default: 256 on the long side).
        scale: the pattern's scale; None chooses it (:func:`export.evidence.choose_points_per_ink`, the
            default :data:`POINTS_PER_INK` unless the pattern is denser). A given scale warns
            (:class:`PatternshopWarning`) when the pattern holds more points than a fully dark map.
        calibrate: scale the ink to the pattern's point count (:func:`export.evidence.calibrate_density`);
            False keeps the network's L.
        denoise: with ``calibrate``, smooth L within its predicted uncertainty (:func:`smooth_reading`); a, b are
            read as without it. A model without ``l_scale`` predicts no uncertainty: its L is not smoothed.
        symmetries: readings averaged over this many symmetries of the square (:func:`predict_symmetric`);
            None: ``config.symmetries``.
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
        symmetries = config.symmetries
    width_px = map_width(points.domain, model, width)
    shape = (max(1, round(width_px * points.domain[1] / points.domain[0])), width_px)
    lab_map, output, pixels_per_unit, l_scale = read_pattern(points, model, scale.points_per_ink, shape, symmetries,
                                                             config.border_px)
    density, factor = lab_map.density().astype(np.float64), None
    ink = len(points) / full_ink_points(scale.points_per_ink, points.domain)
    if calibrate:
        density, factor = calibrate_density(density, ink)
    reading = Inference(with_density(lab_map, density), scale, output, pixels_per_unit, calibration=factor,
                        symmetries=symmetries)
    if l_scale is None:  # no predicted uncertainty to smooth within
        return reading
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
