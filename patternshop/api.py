"""Patternshop's Python API: the workflows of the ``patternshop`` command as typed functions.

``import patternshop as ps`` gives every name below (imported lazily, so ``import patternshop`` stays fast
and loads neither torch nor ONNX Runtime until a function needs them). The CLI's commands call these same
functions. Conventions:

* A **map** is a :class:`~synthesis.labmap.LabMap`: ``lab`` (H, W, 3) float32, L in [0, 100] (density
  ``d = 1 - L/100``: 0 = white, no points; 1 = full ink), a, b in [-128, 127] (the correlation's colour).
  It covers the domain ``[0, w] x [0, h]`` with ``max(w, h) = 1`` (``lab_map.domain``).
* A **pattern** is a :class:`~synthesis.points.PointSet`: ``xy`` (n, 2) float64 in the domain, origin
  top-left, y down; ``domain`` (w, h); optional ``radius`` (n,) in the same units.
* A **correlation** is a preset name (``"blue"``, see :func:`presets`), a text ``"A,B"`` or an (a, b) pair.
* ``points_per_ink`` is :data:`~synthesis.conventions.POINTS_PER_INK_MEANING`:
  ``n = points_per_ink x w x h x mean density`` (default :data:`POINTS_PER_INK`, 50,000). :func:`synthesize`
  records it in its points (``points.points_per_ink``, written into ``.txt`` files), and :func:`infer` reads it.
* Errors a user can cause raise :class:`~synthesis.errors.PatternshopError` with a one-line message;
  losses and guesses warn with :class:`~synthesis.errors.PatternshopWarning`.

Functions, by workflow:

* maps and points: :func:`read_map`, :func:`write_map`, :func:`write_preview`, :func:`read_points`,
  :func:`write_points`; :func:`render_png`, :func:`write_svg` (renderings of a pattern);
* photo -> map: :func:`from_image`; a plain map: :func:`uniform_map`;
* map -> points: :func:`synthesize` (with a ``progress`` callback), :func:`point_count`, :func:`dot_sizes`;
* points -> map: :func:`infer` (the network, :func:`load_model`, :func:`infer_scale`);
* batches: :func:`convert` (a folder of point files to maps, or of maps to point files; folders or fsspec URLs);
* a pattern's correlation: :func:`analyze`, :func:`plot_analysis`;
* map edits (each returns a new map): :func:`set_correlation`, :func:`density_gradient`, :func:`expand`,
  :func:`resize`, with regions from :func:`rect_region` and :func:`read_region`;
* the palette: :func:`presets`, :func:`preset`, :func:`correlation_ab`, :func:`load_palette`.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import os
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Union

from synthesis.conventions import POINTS_PER_INK
from synthesis.errors import PatternshopError

if TYPE_CHECKING:
    import numpy as np

    from export.convert import FileResult
    from export.evidence import ScaleChoice
    from export.infer_config import InferConfig
    from export.runtime import Inference, OnnxModel
    from synthesis.analysis import plot_analysis
    from synthesis.edits import density_gradient, expand, read_region, rect_region, resize
    from synthesis.errors import PatternshopWarning
    from synthesis.labmap import LabMap
    from synthesis.mapio import read_map, write_map, write_preview
    from synthesis.palette import Palette, load_palette
    from synthesis.points import PointSet, read_points, write_points
    from synthesis.render import render_png, write_svg
    from synthesis.synthesize import SynthesisResult, point_count
    from synthesis.tone import dot_sizes

PathLike = Union[str, os.PathLike]
Correlation = Union[str, Sequence[float]]
"""A preset name (``"blue"``), a text ``"A,B"``, or an (a, b) pair, each in [-128, 127]."""
PaletteLike = Union["Palette", PathLike, None]
"""A loaded palette, the path of a palette asset (``.npz``), or None for the shipped one."""
ProgressCallback = Callable[[int, int, "np.ndarray"], object]
"""``progress(done, total, xy)``: iterations done (0 .. total) and the current (n, 2) positions."""

MAX_SEED = 2**32 - 1

# Library functions and classes that already are the right public API: re-exported as they are.
_REEXPORTS = {
    "PatternshopError": "synthesis.errors",
    "PatternshopWarning": "synthesis.errors",
    "LabMap": "synthesis.labmap",
    "PointSet": "synthesis.points",
    "Palette": "synthesis.palette",
    "SynthesisResult": "synthesis.synthesize",
    "Inference": "export.runtime",
    "InferConfig": "export.infer_config",
    "FileResult": "export.convert",
    "OnnxModel": "export.runtime",
    "read_map": "synthesis.mapio",
    "write_map": "synthesis.mapio",
    "write_preview": "synthesis.mapio",
    "read_points": "synthesis.points",
    "write_points": "synthesis.points",
    "render_png": "synthesis.render",
    "write_svg": "synthesis.render",
    "point_count": "synthesis.synthesize",
    "dot_sizes": "synthesis.tone",
    "plot_analysis": "synthesis.analysis",
    "density_gradient": "synthesis.edits",
    "expand": "synthesis.edits",
    "resize": "synthesis.edits",
    "rect_region": "synthesis.edits",
    "read_region": "synthesis.edits",
    "load_palette": "synthesis.palette",
}
_FUNCTIONS = ("analyze", "convert", "correlation_ab", "from_image", "infer", "infer_scale", "load_model", "preset", "presets",
              "set_correlation", "synthesize", "uniform_map")

__all__ = sorted(["POINTS_PER_INK", *_REEXPORTS, *_FUNCTIONS])


def __getattr__(name: str) -> Any:
    if name not in _REEXPORTS:
        raise AttributeError(f"module 'patternshop.api' has no attribute {name!r}")
    return getattr(importlib.import_module(_REEXPORTS[name]), name)  # not cached: always the library's current function


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


# --- inputs -------------------------------------------------------------------------------------------------
def _as_map(lab_map: LabMap | PathLike) -> LabMap:
    """A map, or a map file read with :func:`read_map`."""
    from synthesis.labmap import LabMap
    from synthesis.mapio import read_map

    if isinstance(lab_map, LabMap):
        return lab_map
    if isinstance(lab_map, (str, os.PathLike)):
        return read_map(lab_map)
    raise PatternshopError(f"expected a LabMap or the path of a map file, got {type(lab_map).__name__}")


def _as_points(points: PointSet | PathLike, allow_empty: bool = False) -> PointSet:
    """A pattern, or a point file read with :func:`read_points` (its domain from the file, else the unit square)."""
    from synthesis.points import PointSet, read_points

    if isinstance(points, PointSet):
        return points
    if isinstance(points, (str, os.PathLike)):
        return read_points(points, allow_empty=allow_empty)
    raise PatternshopError(f"expected a PointSet or the path of a point file, got {type(points).__name__}")


def _as_palette(palette: PaletteLike) -> Palette:
    from synthesis.palette import Palette, load_palette

    if isinstance(palette, Palette):
        return palette
    return load_palette(None if palette is None else os.fspath(palette))  # cached: one copy per file and process


def _check_int(name: str, value: object, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low or (high is not None and value > high):
        bounds = f"from {low} to {high}" if high is not None else f"at least {low}"
        raise PatternshopError(f"{name} must be an integer {bounds}, got {value!r}")
    return value


def _check_positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise PatternshopError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


# --- the palette --------------------------------------------------------------------------------------------
def presets(palette: PaletteLike = None) -> dict[str, tuple[float, float]]:
    """The palette's named correlations: name -> (a, b), each in [-128, 127].

    Example: ``presets()["blue"]`` is ``(24.0, -52.0)`` for the shipped palette (blue noise); the names are
    white, blue, green, red, step, lattice, lloyd and matern (``jitter`` and ``perturbed`` were merged into step
    and lloyd: :func:`preset` still takes them, with a warning).
    """
    return _as_palette(palette).preset_ab()


def preset(name: str, palette: PaletteLike = None) -> tuple[float, float]:
    """The (a, b) colour of the preset ``name``.

    Raises:
        PatternshopError: no preset of that name (the message lists them).
    """
    return _as_palette(palette).preset(name)


def correlation_ab(correlation: Correlation, palette: PaletteLike = None) -> tuple[float, float]:
    """A correlation as its (a, b) colour: a preset name (``"green"``), a text ``"A,B"`` or an (a, b) pair.

    The palette is loaded only for a name.

    Raises:
        PatternshopError: an unknown name, or a colour that is not two finite numbers in [-128, 127].
    """
    from synthesis.palette import MERGED_PRESETS
    from synthesis.photo import check_ab, parse_correlation

    if isinstance(correlation, str):
        text = correlation.strip()
        if "," not in text and text in MERGED_PRESETS:
            return preset(text, palette)
        return parse_correlation(text, {} if "," in text else presets(palette))
    try:
        values = [float(v) for v in correlation]
    except (TypeError, ValueError):
        raise PatternshopError(f"a correlation is a preset name, 'A,B' or an (a, b) pair, got {correlation!r}") from None
    if len(values) != 2:
        raise PatternshopError(f"a correlation colour is two numbers (a, b), got {len(values)}")
    return check_ab(values)


# --- maps ---------------------------------------------------------------------------------------------------
def uniform_map(width: int, height: int | None = None, *, density: float = 0.5, correlation: Correlation = "blue",
                palette: PaletteLike = None) -> LabMap:
    """A map of one density and one correlation everywhere: the blank canvas of an ab-initio design.

    Args:
        width, height: size in pixels (height defaults to width: a square map, domain 1 x 1).
        density: in [0, 1] (``L = 100 (1 - density)``).
        correlation: preset name, ``"A,B"`` or (a, b).

    Example: ``uniform_map(64, density=0.3, correlation="green")``.
    """
    import numpy as np

    from synthesis.labmap import LabMap

    width = _check_int("width", width, 1)
    height = width if height is None else _check_int("height", height, 1)
    if isinstance(density, bool) or not isinstance(density, (int, float)) or not 0.0 <= density <= 1.0:
        raise PatternshopError(f"density must be a number in [0, 1], got {density!r}")
    a, b = correlation_ab(correlation, palette)
    return LabMap(np.broadcast_to(np.array([100.0 * (1.0 - density), a, b], np.float32), (height, width, 3)))


def from_image(
    photo: PathLike,
    *,
    correlation: Correlation = "blue",
    levels: Sequence[float] = (0.0, 255.0),
    gamma: float = 1.0,
    invert: bool = False,
    labels: PathLike | None = None,
    label_correlations: Mapping[int | tuple[int, int, int] | str, Correlation] | None = None,
    mask: PathLike | None = None,
    mask_correlation: Correlation | None = None,
    max_side: int = 1024,
    palette: PaletteLike = None,
) -> LabMap:
    """A map from a photo whose stipple reproduces the photo's tone (``patternshop from-image``).

    L is 100 x the photo's *linear* luminance Y (so density = 1 - Y; see :mod:`synthesis.photo`); the
    correlation is ``correlation`` everywhere, then per label or through a mask.

    Args:
        photo: any image Pillow reads (8/16-bit grey, RGB, RGBA, palette); EXIF orientation applied,
            transparent pixels are paper (no points).
        correlation: of every pixel not set by labels or the mask: preset name, ``"A,B"`` or (a, b).
        levels: (black, white) grey values on the photo's 0-255 sRGB scale, 0 <= black < white <= 255.
        gamma: tone curve ``Y' = Y ** gamma`` after the levels, > 0 (> 1: darker mid-tones, more points).
        invert: white dots on black paper: density = Y' instead of 1 - Y'.
        labels: a label image of the photo's size; with ``label_correlations``.
        label_correlations: label key -> correlation. A key is a grey value or palette index (``0``, ``255``
            or ``"255"``), a colour ``(r, g, b)`` or ``"#rrggbb"``.
        mask: a greyscale image of the photo's size: white gets ``mask_correlation``, black keeps
            ``correlation``, grey blends.
        mask_correlation: the correlation where the mask is white.
        max_side: the map's long side in pixels, 1-4096; larger photos are downsampled (with a warning).
        palette: the palette preset names refer to.

    Returns:
        A map with the (downsampled) photo's pixels; its domain is the photo's aspect ratio, long side 1.

    Raises:
        PatternshopError: an unreadable image, a bad option, labels or a mask of another size, or a label
            key that does not occur in the label image.
    """
    from synthesis.photo import parse_label_key, photo_to_map

    label_ab = {(parse_label_key(key) if isinstance(key, str) else key): correlation_ab(value, palette)
                for key, value in (label_correlations or {}).items()}
    if mask is not None and mask_correlation is None:
        raise PatternshopError("a mask needs mask_correlation (the correlation where the mask is white)")
    mask_ab = correlation_ab(mask_correlation, palette) if mask_correlation is not None else None
    return photo_to_map(photo, correlation_ab(correlation, palette), gamma=gamma, levels=levels, invert=invert,
                        labels=labels, label_ab=label_ab, mask=mask, mask_ab=mask_ab, max_side=max_side)


def set_correlation(lab_map: LabMap, correlation: Correlation, region: np.ndarray | None = None,
                    palette: PaletteLike = None) -> LabMap:
    """The map with its correlation (a, b) set to ``correlation`` inside ``region``; L unchanged.

    Args:
        correlation: preset name, ``"A,B"`` or (a, b).
        region: (H, W) weights in [0, 1] (1: set, 0: keep, between: blend), e.g. from :func:`rect_region`
            or :func:`read_region`; None: everywhere.

    Example: ``set_correlation(m, "step", 1 - rect_region((m.height, m.width), (0.3, 0.3, 0.7, 0.7)))``
    makes everything outside the box step noise.
    """
    from synthesis.edits import set_correlation as set_ab

    return set_ab(lab_map, correlation_ab(correlation, palette), region)


# --- map -> points ------------------------------------------------------------------------------------------
def synthesize(
    lab_map: LabMap | PathLike,
    *,
    points: int | None = None,
    points_per_ink: float = POINTS_PER_INK,
    iterations: int | None = None,
    seed: int = 0,
    dot_sizes: bool = False,
    schedule: str = "fast",
    palette: PaletteLike = None,
    threads: int = 1,
    progress: ProgressCallback | None = None,
    progress_bar: bool = False,
) -> SynthesisResult:
    """Points whose density follows the map's L and whose correlation its a, b (``patternshop synthesize``).

    Args:
        lab_map: the map, or the path of a map file.
        points: how many points, >= 2 (default: :func:`point_count`, ``points_per_ink`` x w x h x mean density).
        points_per_ink: points per unit area of full ink, > 0, when ``points`` is not given.
        iterations: optimisation steps (default: the schedule's 250; fewer are faster and rougher).
        seed: 0 to 2**32 - 1; the same seed (and ``threads``) gives the same points.
        dot_sizes: give each point a radius so that the rendering reproduces the map's tone.
        schedule: the optimisation schedule (only ``"fast"``).
        palette: the palette a, b refer to.
        threads: CPU threads of the optimiser (1 is best on a busy machine).
        progress: called as ``progress(done, total, xy)`` with the iterations done, 0 (the density-matched
            start) to ``total``, and the current (n, 2) positions, a live view in an internal order: copy
            to keep.
        progress_bar: show a progress bar on stderr.

    Returns:
        A :class:`~synthesis.synthesize.SynthesisResult`: ``.points`` (a :class:`PointSet` on the map's
        domain), ``.losses`` (one per iteration), ``.final_loss``, ``.seconds``, ``.report()`` (a JSON-ready
        dict).

    Raises:
        PatternshopError: a white map (no ink) without ``points``, or a bad option.
    """
    from synthesis.synthesize import SCHEDULES, point_count
    from synthesis.synthesize import synthesize as run_synthesis

    lab_map = _as_map(lab_map)
    _check_int("seed", seed, 0, MAX_SEED)
    _check_int("threads", threads, 1)
    if points is None:
        points = point_count(lab_map, _check_positive("points_per_ink", points_per_ink))
    _check_int("points", points, 2)
    if iterations is not None:
        _check_int("iterations", iterations, 0)
    if schedule not in SCHEDULES:
        raise PatternshopError(f"unknown schedule {schedule!r}; choose one of: {', '.join(SCHEDULES)}")
    total = iterations if iterations is not None else SCHEDULES[schedule].iterations
    on_iteration = None if progress is None else (lambda done, xy: progress(done, total, xy))
    result = run_synthesis(lab_map, n=points, palette=_as_palette(palette), schedule=schedule, iterations=iterations,
                           seed=seed, threads=threads, progress=progress_bar, on_iteration=on_iteration)
    if dot_sizes:
        from synthesis.tone import dot_sizes as sized

        result = dataclasses.replace(result, points=sized(result.points, lab_map))
    return result


# --- points -> map ------------------------------------------------------------------------------------------
def load_model(path: PathLike | None = None, *, threads: int = 1) -> OnnxModel:
    """The points-to-map network (ONNX Runtime, CPU): ``path`` or the shipped default model.

    Warns (:class:`PatternshopWarning`) when the model was trained with another palette than the shipped one.
    Load it once and pass it to :func:`infer` to infer many patterns.

    Raises:
        PatternshopError: a missing or unreadable file, or not a Patternshop model.
    """
    from export.runtime import OnnxModel, check_palette

    model = OnnxModel(path, threads=_check_int("threads", threads, 1))
    check_palette(model)
    return model


def infer_scale(points: PointSet, points_per_ink: float | None = None, *, config: InferConfig | None = None) -> ScaleChoice:
    """The scale :func:`infer` reads a pattern at: ``points_per_ink`` if given (> 0), else the one its file's
    header records (``points.points_per_ink``, written by :func:`synthesize`), else 50,000 unless the pattern is
    denser somewhere (then the scale at which its densest 1% reads as full ink; ``config``: the constants of
    that choice, default :data:`export.infer_config.DEFAULT_INFER`).

    Returns an :class:`~export.evidence.ScaleChoice` (``.points_per_ink``, ``.automatic``, ``.describe()``).
    """
    from export.evidence import pattern_scale
    from export.infer_config import DEFAULT_INFER

    return pattern_scale(points, None if points_per_ink is None else _check_positive("points_per_ink", points_per_ink),
                         config or DEFAULT_INFER)


def infer(
    points: PointSet | PathLike,
    *,
    model: OnnxModel | PathLike | None = None,
    points_per_ink: float | ScaleChoice | None = None,
    width: int | None = None,
    symmetries: int | None = None,
    calibrate: bool = True,
    denoise: bool = True,
    threads: int = 1,
    config: InferConfig | None = None,
) -> Inference:
    """The map (density and correlation) of a point pattern, read by the network (``patternshop infer``).

    Args:
        points: the pattern, or the path of a point file (an empty pattern gives a white map).
        model: a model from :func:`load_model`, the path of an ``.onnx`` model, or None for the shipped one.
        points_per_ink: points per unit area of full ink at the pattern's scale, > 0, or the
            :class:`~export.evidence.ScaleChoice` :func:`infer_scale` returned for these points (not chosen again;
            default: :func:`infer_scale`: the point file's header, written by :func:`synthesize`, else chosen from the points).
        width: map width in pixels, >= 1 (default: 256 px on the domain's long side).
        symmetries: average the network over 8 (flips and transposes), 4 (flips), 2 or 1 symmetries, one network
            pass each (default: ``config.symmetries``).
        calibrate: scale the ink so that the map holds the pattern's point count (False: the network's L;
            then ``denoise`` does nothing).
        denoise: smooth L within the uncertainty the model predicts (its ``l_scale`` output; a model without one:
            L is not smoothed).
        threads: ONNX Runtime threads, when the model is loaded here.
        config: the constants around the network (default :data:`export.infer_config.DEFAULT_INFER`).

    Returns:
        An :class:`~export.runtime.Inference`: ``.lab_map`` (the map, on the pattern's domain), ``.scale``,
        ``.l_scale`` and ``.report()`` (a JSON-ready dict).

    Raises:
        PatternshopError: a missing model or point file, or a bad option.
    """
    from export.evidence import ScaleChoice
    from export.infer_config import DEFAULT_INFER
    from export.runtime import OnnxModel, infer_map

    points = _as_points(points, allow_empty=True)
    if width is not None:
        _check_int("width", width, 1)
    if not isinstance(model, OnnxModel):
        model = load_model(model, threads=threads)
    scale = points_per_ink if isinstance(points_per_ink, ScaleChoice) else infer_scale(points, points_per_ink, config=config)
    return infer_map(points, model, width=width, scale=scale, calibrate=calibrate, symmetries=symmetries,
                     denoise=denoise, config=config or DEFAULT_INFER)


# --- batches ------------------------------------------------------------------------------------------------
def convert(
    in_dir: PathLike,
    out_dir: PathLike,
    *,
    resynthesize: bool = False,
    model: OnnxModel | PathLike | None = None,
    workers: int = 2,
    threads: int = 1,
    scheduler: str | None = None,
    batch_size: int = 8,
    overwrite: bool = False,
    max_memory_gb: float | None = None,
    progress_bar: bool = False,
    points_per_ink: float | None = None,
    bits: int = 16,
    symmetries: int | None = None,
    denoise: bool = True,
    config: InferConfig | None = None,
    points: int | None = None,
    schedule: str = "fast",
    iterations: int | None = None,
    seed: int = 0,
    palette: PathLike | None = None,
) -> list[FileResult]:
    """Convert a folder (``patternshop convert``): infer ``out_dir/NAME.tif`` for every point file in ``in_dir``
    (.txt, .csv, .xy, .pts, .npy), or with ``resynthesize`` synthesise ``out_dir/NAME.txt`` for every map.

    Both folders may be local paths or fsspec URLs (``file://``, ``s3://`` / ``gs://`` with s3fs / gcsfs installed;
    ``memory://`` works in this process only, so it runs with one worker). Outputs are written atomically, existing
    ones skipped unless ``overwrite`` (a rerun resumes), and a bad file fails alone (its result says why).

    Args:
        resynthesize: maps to points (the synthesiser) instead of points to maps (the network).
        model: points to maps: a model from :func:`load_model`, the path of an ``.onnx`` model, or None for the
            shipped one (workers load it by path).
        workers: local worker processes, each started once (1: this process); ignored with ``scheduler``.
        threads: CPU threads per worker (ONNX Runtime, or the synthesiser).
        scheduler: a Dask scheduler's address (``tcp://host:8786``): run on its workers, which must reach both
            folders at the same absolute paths or URLs (docs/distributed.md).
        batch_size: point files per worker task at most (fewer in a short run, so that the workers end together).
        max_memory_gb: the memory all workers together may use; a file whose estimate exceeds its worker's share
            fails (None: no limit).
        progress_bar: show a progress bar on stderr.
        points_per_ink: the scale point files are read at (default: per file, as :func:`infer`), and maps
            synthesised at with ``resynthesize`` (default 50,000).
        bits: 8 or 16 bits per sample of the output TIFFs.
        symmetries: network readings averaged per file: 1, 2, 4 or 8 (default: ``config.convert_symmetries``, 1, for
            throughput).
        denoise: smooth L as :func:`infer` does (for a model without ``l_scale``, about twice the network time).
        config: the constants around the network (default :data:`export.infer_config.DEFAULT_INFER`).
        points, schedule, iterations, seed, palette: ``resynthesize`` only, as in :func:`synthesize` (every map
            gets the same seed); ``palette`` the path of a palette asset.

    Returns:
        One :class:`~export.convert.FileResult` per input, sorted by name: ``.source``, ``.output``, ``.status``
        (``"written"``, ``"skipped"``: its output existed, or ``"failed"``), ``.error`` and ``.warnings``.

    Raises:
        PatternshopError: a missing folder, a folder without inputs, a missing model, or a bad option.
    """
    from export.convert import SynthesisSettings, convert_points, map_files, point_files, resynthesize_maps

    _check_int("workers", workers, 1)
    _check_int("threads", threads, 1)
    memory_limit = math.inf if max_memory_gb is None else _check_positive("max_memory_gb", max_memory_gb) * 1e9
    if points_per_ink is not None:
        _check_positive("points_per_ink", points_per_ink)
    if resynthesize:
        if model is not None:
            raise PatternshopError("a model does not apply to resynthesize (maps to points uses the synthesiser)")
        _check_int("seed", seed, 0, MAX_SEED)
        sources = map_files(in_dir)
        if not sources:
            raise PatternshopError(f"{in_dir}: no maps (.tif, .tiff, .png, .jpg, .jpeg, channel PNGs NAME.L.png)")
        settings = SynthesisSettings(points=points, points_per_ink=points_per_ink, schedule=schedule,
                                     iterations=iterations, seed=seed,
                                     palette=None if palette is None else os.fspath(palette))
        return resynthesize_maps(sources, out_dir, settings, workers=workers, threads=threads, overwrite=overwrite,
                                 progress=progress_bar, memory_limit=memory_limit, scheduler=scheduler)
    from export.infer_config import DEFAULT_INFER, SYMMETRY_CHOICES
    from export.runtime import OnnxModel

    _check_int("batch_size", batch_size, 1)
    if symmetries is not None and symmetries not in SYMMETRY_CHOICES:
        raise PatternshopError(f"symmetries must be one of {', '.join(map(str, SYMMETRY_CHOICES))}, got {symmetries!r}")
    sources = point_files(in_dir)
    if not sources:
        raise PatternshopError(f"{in_dir}: no point files (.txt, .csv, .xy, .pts, .npy)")
    if not isinstance(model, OnnxModel):
        model = load_model(model, threads=threads)
    return convert_points(sources, out_dir, model, batch_size=batch_size, workers=workers, bits=bits,
                          overwrite=overwrite, progress=progress_bar, points_per_ink=points_per_ink,
                          memory_limit=memory_limit, symmetries=symmetries, denoise=denoise, scheduler=scheduler,
                          config=config or DEFAULT_INFER)


# --- a pattern's correlation --------------------------------------------------------------------------------
def analyze(points: PointSet | PathLike, *, palette: PaletteLike = None, progress_bar: bool = False) -> dict[str, Any]:
    """The correlation of a stationary pattern (``patternshop analyze``).

    Returns a JSON-ready dict: ``n``, ``domain``; the palette colour ``a``, ``b`` (each in [-128, 127]),
    ``hue`` (degrees), ``chroma``, ``nearest_preset``, ``confidence`` and ``exemplar_distance`` (in exemplar
    spacings of the palette's corpus); the PCF ``r`` (in units of ``r_max``), ``pcf``; the radial power
    spectrum ``frequency`` (cycles per window side), ``spectrum`` (1 for Poisson). :func:`plot_analysis`
    draws it. Warns (:class:`PatternshopWarning`) when the pattern lies outside the palette's corpus (the
    result then also has ``warning``). ``progress_bar``: show a progress bar on stderr.

    Raises:
        PatternshopError: a degenerate pattern (most points on top of each other).
    """
    import warnings

    from synthesis.analysis import analyze_points
    from synthesis.errors import PatternshopWarning

    result = analyze_points(_as_points(points), _as_palette(palette), progress=progress_bar)
    if "warning" in result:
        warnings.warn(result["warning"], PatternshopWarning, stacklevel=2)
    return result
