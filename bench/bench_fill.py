"""Pattern expansion's fill (issue 30, the paper's Fig. 9): does the new margin get more of the map's texture?

On procedural tree-cover-like maps (density: forest patches of 1/f noise, soft-thresholded, with a canopy
grain; correlation: the paper's anisotropic Gaussian kernels, :func:`data_gen.chroma.gaussian_field_chroma`)
a margin is hidden (25 % of the side, on the right, or on the right and at the bottom) and filled again by

* ``edge``: repeating the edge pixels (``edit --expand``'s default),
* ``biharmonic``: smooth inpainting (scikit-image's ``inpaint_biharmonic``, a dev dependency),
* ``content-aware``: :func:`synthesis.patchfill.content_aware_fill` (``--fill content-aware``).

Per method and map: the Wasserstein-1 distance of the filled margin's L values to the hidden truth's, and the
mean absolute log ratio of their radially averaged L power spectra (mean removed, Hann window, per hidden
strip); medians and per-map wins. Then the content-aware fill's time to expand a 256^2 and a 1024^2 map by 25 %.
Writes ``out/bench/fill.json`` and a picture sheet ``out/bench/fill_sheet.png`` (rows: maps; columns: truth,
edge, biharmonic, content-aware).

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_fill.py [--maps 8] [--size 256]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.stats import wasserstein_distance

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import RESULTS_DIR, save_results  # noqa: E402 - bench/ is not a package

from data_gen.chroma import gaussian_field_chroma  # noqa: E402
from data_gen.makers.procedural import Canvas  # noqa: E402
from synthesis.labmap import LabMap  # noqa: E402
from synthesis.palette import load_palette  # noqa: E402
from synthesis.patchfill import content_aware_fill  # noqa: E402

Strip = tuple[slice, slice]


def treecover_like(size: int, seed: int) -> LabMap:
    """A (size, size) tree-cover-like map: forests and clearings (Gaussian-smoothed noise, sigma in [0.015, 0.04] map
    units, through a soft threshold: dozens of patches a map) times a canopy grain (1/f^beta noise, beta in
    [0.6, 1.0]); chroma from 2-16 anisotropic Gaussians."""
    rng = np.random.default_rng([30, seed])
    canvas = Canvas(size, rng)
    patches = canvas.spectral_noise(sigma=rng.uniform(0.015, 0.04))
    forest = 1.0 / (1.0 + np.exp(-(patches - rng.uniform(0.35, 0.65)) / rng.uniform(0.02, 0.08)))
    grain = canvas.spectral_noise(beta=rng.uniform(0.6, 1.0))
    density = np.clip(forest * (0.45 + 0.55 * grain), 0.0, 1.0)
    return LabMap.from_density_latent(density, gaussian_field_chroma((size, size), rng, load_palette()))


def hidden_strips(shape: tuple[int, int], sides: int, share: float = 0.25) -> list[Strip]:
    """The hidden margin as strips (rows, columns): the right ``share`` of the width, and with ``sides`` = 2 also the
    bottom ``share`` of the height (left of the right strip)."""
    height, width = shape
    right = (slice(0, height), slice(width - round(share * width), width))
    if sides == 1:
        return [right]
    return [right, (slice(height - round(share * height), height), slice(0, width - round(share * width)))]


def radial_power(plane: np.ndarray, bins: int) -> np.ndarray:
    """(bins,) radially averaged power spectrum of an (h, w) plane, mean removed and Hann-windowed; frequencies in
    cycles per pixel from 0 to 0.5 in ``bins`` rings (the DC ring excluded)."""
    window = np.outer(np.hanning(plane.shape[0]), np.hanning(plane.shape[1]))
    power = np.abs(np.fft.fft2((plane - plane.mean()) * window)) ** 2 / plane.size
    radius = np.hypot(*np.meshgrid(np.fft.fftfreq(plane.shape[0]), np.fft.fftfreq(plane.shape[1]), indexing="ij"))
    ring = np.minimum((radius / 0.5 * bins).astype(int), bins)  # bins = beyond Nyquist along a diagonal
    sums = np.bincount(ring.ravel(), power.ravel(), bins + 1)[:bins]
    counts = np.bincount(ring.ravel(), minlength=bins + 1)[:bins]
    return sums[1:] / np.maximum(counts[1:], 1)


def spectrum_distance(filled: np.ndarray, truth: np.ndarray, strips: list[Strip], bins: int = 24) -> float:
    """Mean over strips and rings of |log(P_filled / P_truth)| of the L channel's radial power (see :func:`radial_power`)."""
    eps = 1e-4  # L^2 per ring: a blank strip (no trees) is not infinitely far from one with a few
    return float(np.mean([np.mean(np.abs(np.log((radial_power(filled[s], bins) + eps) / (radial_power(truth[s], bins) + eps))))
                          for s in strips]))


def histogram_distance(filled: np.ndarray, truth: np.ndarray, hole: np.ndarray) -> float:
    """Wasserstein-1 distance (L units) between the L values of ``filled`` and ``truth`` in the hole."""
    return float(wasserstein_distance(filled[hole], truth[hole]))


def edge_fill(lab: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """Repeat the edge pixels of the known top-left rectangle into the hidden margin (``edit --expand``'s default)."""
    rows, cols = np.nonzero(~hole)
    known = lab[: rows.max() + 1, : cols.max() + 1]
    return np.pad(known, ((0, lab.shape[0] - known.shape[0]), (0, lab.shape[1] - known.shape[1]), (0, 0)), mode="edge")


def biharmonic_fill(lab: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """scikit-image's biharmonic inpainting, all three channels (a smooth continuation)."""
    from skimage.restoration import inpaint_biharmonic

    return inpaint_biharmonic(lab.astype(np.float64), hole, channel_axis=-1).astype(np.float32)


def patch_fill(lab: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """:func:`synthesis.patchfill.content_aware_fill` with its defaults, seed 0."""
    return content_aware_fill(lab, hole, seed=0)


METHODS: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "edge": edge_fill, "biharmonic": biharmonic_fill, "content-aware": patch_fill}


def expansion_seconds(size: int) -> float:
    """Seconds to fill a 25 % right margin of a (size, size) tree-cover-like map enlarged to (size, 1.25 size)."""
    lab = treecover_like(size, 0).lab
    margin = size // 4
    canvas = np.pad(lab, ((0, 0), (0, margin), (0, 0)), mode="edge")
    hole = np.zeros(canvas.shape[:2], bool)
    hole[:, size:] = True
    start = time.perf_counter()
    content_aware_fill(canvas, hole, seed=0)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", type=int, default=8)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--sheet-maps", type=int, default=4, help="maps shown in the picture sheet")
    parser.add_argument("--timing-sizes", type=int, nargs="*", default=[256, 1024], help="map sides to time expansion on")
    args = parser.parse_args()
    content_aware_fill(np.zeros((16, 16, 3), np.float32), np.eye(16, dtype=bool), patch=3)  # compile the kernels
    rows, sheet = [], []
    for seed in range(args.maps):
        truth = treecover_like(args.size, seed).lab
        strips = hidden_strips(truth.shape[:2], 1 + seed % 2)
        hole = np.zeros(truth.shape[:2], bool)
        for strip in strips:
            hole[strip] = True
        row, tiles = {"map": seed, "sides": len(strips)}, [truth]
        for name, method in METHODS.items():
            start = time.perf_counter()
            filled = method(np.where(hole[..., None], 0.0, truth).astype(np.float32), hole)
            row[name] = {"histogram_w1": histogram_distance(filled[..., 0], truth[..., 0], hole),
                         "spectrum_log_ratio": spectrum_distance(filled[..., 0], truth[..., 0], strips),
                         "seconds": time.perf_counter() - start}
            tiles.append(filled)
        print(f"map {seed} ({len(strips)} sides)  " + "  ".join(f"{name}: W1 {row[name]['histogram_w1']:5.2f} spec {row[name]['spectrum_log_ratio']:4.2f}"
                          for name in METHODS), flush=True)
        rows.append(row)
        if seed < args.sheet_maps:
            sheet.append(np.concatenate([LabMap(t).to_srgb8() for t in tiles], axis=1))
    summary = {}
    for metric in ("histogram_w1", "spectrum_log_ratio"):
        for name in METHODS:
            others = [other for other in METHODS if other != name]
            summary.setdefault(name, {})[metric] = {
                "median": statistics.median(r[name][metric] for r in rows),
                "wins_over_all_others": sum(all(r[name][metric] < r[o][metric] for o in others) for r in rows)}
    timings = {f"{size}px": expansion_seconds(size) for size in args.timing_sizes}
    print(f"\n{'method':14s} {'W1 median':>10s} {'wins':>5s} {'spectrum median':>16s} {'wins':>5s}")
    for name in METHODS:
        h, s = summary[name]["histogram_w1"], summary[name]["spectrum_log_ratio"]
        print(f"{name:14s} {h['median']:10.2f} {h['wins_over_all_others']:5d} {s['median']:16.2f} {s['wins_over_all_others']:5d}")
    print("content-aware expansion by 25 %: " + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items()))
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(sheet, axis=0)).save(RESULTS_DIR / "fill_sheet.png")
    save_results("fill", {"maps": rows, "summary": summary, "expansion_seconds": timings, "size": args.size})


if __name__ == "__main__":
    main()
