"""Peak-memory estimates of the heavy steps, in bytes, from the sizes of their inputs (no numpy: the CLI checks them first).

Each figure was measured with ``/usr/bin/time -f %M`` (peak resident memory) on
the 2-core development machine and rounded up; the interpreter with numpy
takes about 0.1 GB of it. The CLI refuses work whose estimate exceeds
``--max-memory-gb`` (:func:`patternshop.commands.check_memory`).
"""

from __future__ import annotations

BASE = 0.2e9  # interpreter, numpy, Pillow, tifffile
MAP_BYTES_PER_PIXEL = 150  # read_map with its colour conversion (1000 x 1000 px: 0.14 GB over the base)
TEXT_POINTS_BYTES_PER_FILE_BYTE = 12  # read_points of text (1M points, 24 MB: 0.2 GB peak)
NPY_POINTS_BYTES_PER_FILE_BYTE = 4
SYNTHESIS_BASE = 0.3e9  # synthesis (20k / 100k / 1M points on a 256^2 map: 0.29 / 0.40 / 1.43 GB on 1 thread;
# bench_speed.py with 2 threads: 10k 0.28, 100k 0.41, 300k 0.75, 1M 1.53 GB; synthesis v3 (f5a0055): 100k 0.47,
# 300k 0.99, 1M 2.19 GB; 2.35 GB in a run that compiled the kernels; after the memory round of issue 27 (refresh buffers
# shared, no copies of the window sums, final_loss after the run's lists are dropped): 100k 0.37 (1 thread), 300k 0.68,
# 1M 1.44 GB on 2 threads, warm kernel cache; compiling adds about 0.15 GB)
SYNTHESIS_BYTES_PER_POINT = 1.3e3  # 300k on 2 threads needs 1.23e3 over the base and the 256^2 map, 1M 1.12e3 (about
# 1.27e3 with the 0.15 GB that compiling the kernels added to v3)
SYNTHESIS_BYTES_PER_PIXEL = 180
RENDER_BYTES_PER_PIXEL = 100  # render_png: supersampled span counts and the grey image, per output pixel
NETWORK_BYTES_PER_RASTER_PIXEL = 260  # ONNX Runtime, default generator exported fused, 8 symmetries averaged, zoomed readings (a 2176^2 px raster: 1.40 GB; 1 symmetry 1.09 GB)
INFERRED_MAP_BYTES_PER_PIXEL = 80  # decoding, resampling and writing the inferred map (4000 x 2667 px: 1.0 GB)
PREVIEW_BYTES_PER_OUTPUT_PIXEL = 5  # the enlarged RGB image and its PNG encoding (64M px: 0.11 GB)
EDIT_BYTES_PER_OUTPUT_PIXEL = 100  # expanded map, region, blend and TIFF encoding (3000 x 3000 px: 0.7 GB)
ANALYSIS_BASE = 0.7e9  # analyze: 0.58 GB peak from 20k to 1M points (PCF in chunks)
ANALYSIS_BYTES_PER_POINT = 200
PALETTE_PICTURE_BYTES_PER_PIXEL = 20  # RGB canvas, cells and PNG encoding
EXPORT_BASE = 1e9  # torch, Lightning and the generator
EXPORT_CHECK_BYTES_PER_PIXEL = 400  # one batch through torch and ONNX Runtime


def point_file_bytes(file_size: int, npy: bool) -> float:
    """Reading a point file of ``file_size`` bytes (``.npy`` or text)."""
    return BASE + (NPY_POINTS_BYTES_PER_FILE_BYTE if npy else TEXT_POINTS_BYTES_PER_FILE_BYTE) * file_size


def map_bytes(pixels: int) -> float:
    """Reading (and converting) a map of ``pixels`` pixels."""
    return BASE + MAP_BYTES_PER_PIXEL * pixels


def synthesis_bytes(pixels: int, points: int) -> float:
    """Synthesising ``points`` points on a map of ``pixels`` pixels."""
    return SYNTHESIS_BASE + SYNTHESIS_BYTES_PER_PIXEL * pixels + SYNTHESIS_BYTES_PER_POINT * points


def render_bytes(width_px: int, height_px: int) -> float:
    """Rendering dots into a PNG of ``width_px`` x ``height_px``."""
    return RENDER_BYTES_PER_PIXEL * width_px * height_px


def inference_bytes(raster_side: int, map_pixels: int) -> float:
    """The network on one (side x side) raster, then a map (and preview) of ``map_pixels``."""
    return BASE + NETWORK_BYTES_PER_RASTER_PIXEL * raster_side**2 + INFERRED_MAP_BYTES_PER_PIXEL * map_pixels


def preview_bytes(pixels: int, scale: int) -> float:
    """A preview of a ``pixels``-pixel map enlarged ``scale`` times."""
    return map_bytes(pixels) + PREVIEW_BYTES_PER_OUTPUT_PIXEL * pixels * scale**2


def edit_bytes(pixels: int, output_pixels: int) -> float:
    """Editing a ``pixels``-pixel map into one of ``output_pixels`` (after --expand)."""
    return map_bytes(pixels) + EDIT_BYTES_PER_OUTPUT_PIXEL * output_pixels


def analysis_bytes(points: int) -> float:
    """``analyze`` of ``points`` points."""
    return ANALYSIS_BASE + ANALYSIS_BYTES_PER_POINT * points


def palette_picture_bytes(side_px: int) -> float:
    """A palette picture of ``side_px`` x ``side_px``."""
    return BASE + PALETTE_PICTURE_BYTES_PER_PIXEL * side_px**2


def export_check_bytes(rasters: int, raster_side: int) -> float:
    """``export``: the generator, and the torch/ONNX comparison on ``rasters`` rasters of ``raster_side``."""
    return EXPORT_BASE + EXPORT_CHECK_BYTES_PER_PIXEL * rasters * raster_side**2
