"""Make the bundled example maps in ``examples/`` (settings: ``conf/examples.yaml``).

* ``logo.tif`` (384 x 256): a logo-like map with varying density and three
  correlation regions split by sharp edges: background (blue noise), a disc
  (green noise) and a bold letter "P" (red, clustered) — colours are the
  shipped palette's presets.
* ``gradient.tif`` (256 x 256): density rising smoothly left to right, and the
  correlation moving smoothly from blue noise (top) to green noise (bottom).

Each map is written as a 16-bit CIELAB TIFF with an sRGB preview PNG beside it.
Then, for each map named in ``points.maps``, the synthesiser (fast schedule,
fixed seed) turns the written TIFF into ``NAME_points.txt``: ``logo_points.txt``
(about 7,200 points at 20,000 points per ink) is the input pattern of the demo
loop, ``examples/demo.py``.
Usage: ``python examples/make_examples.py [key=value ...]`` (Hydra overrides).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from data_gen.provenance import CONF_DIR
from synthesis.labmap import LabMap
from synthesis.mapio import read_map, write_map, write_preview
from synthesis.palette import load_palette
from synthesis.points import write_points
from synthesis.synthesize import point_count, synthesize



def pixel_centres(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) x and y of pixel centres in map units (longer side 1, y down)."""
    side = max(width, height)
    x = (np.arange(width) + 0.5) / side
    y = (np.arange(height) + 0.5) / side
    return np.meshgrid(x, y)


def lab_from_parts(density: np.ndarray, ab: np.ndarray) -> LabMap:
    """Map from density (H, W) in [0, 1] and chroma (H, W, 2) in [-128, 127]."""
    return LabMap(np.concatenate([(100.0 * (1.0 - density))[..., None], ab], axis=-1))


def letter_p(x: np.ndarray, y: np.ndarray, left: float, top: float, size: float) -> np.ndarray:
    """Boolean mask of a bold sans-serif "P" whose box is ``size`` high at (left, top)."""
    stem = (x >= left) & (x <= left + 0.22 * size) & (y >= top) & (y <= top + size)
    cx, cy, r_out = left + 0.3 * size, top + 0.3 * size, 0.3 * size
    r = np.hypot(x - cx, y - cy)
    bowl = (r <= r_out) & (r >= 0.12 * size) & (x >= cx)
    bars = (x >= left) & (x <= cx) & (((y >= top) & (y <= top + 0.18 * size)) | ((y >= top + 0.42 * size) & (y <= top + 0.6 * size)))
    return stem | bowl | bars


def resolve_colors(colors: DictConfig) -> dict[str, np.ndarray]:
    """Colour names -> (a, b): palette preset names are looked up, [a, b] pairs kept."""
    presets = load_palette().preset_ab()
    resolved = {}
    for name, value in colors.items():
        if isinstance(value, str):
            if value not in presets:
                raise SystemExit(f"unknown preset '{value}' (palette presets: {', '.join(presets)})")
            value = presets[value]
        resolved[name] = np.asarray(value, np.float64)
    return resolved


def make_logo(cfg: DictConfig, colors: dict[str, np.ndarray]) -> LabMap:
    x, y = pixel_centres(cfg.width, cfg.height)
    w = x.max() + x.min()
    lo, hi = cfg.background_density
    density = lo + (hi - lo) * x / w
    ab = np.broadcast_to(colors["blue"], x.shape + (2,)).copy()

    centre, radius = (0.3, 0.33), 0.24
    r = np.hypot(x - centre[0], y - centre[1]) / radius
    disc = r <= 1.0
    rim, core = cfg.disc_density
    density[disc] = (core + (rim - core) * r**2)[disc]
    ab[disc] = colors["green"]

    letter = letter_p(x, y, left=0.62, top=0.13, size=0.42)
    density[letter] = cfg.letter_density
    ab[letter] = colors["red"]
    return lab_from_parts(density, ab)


def make_gradient(cfg: DictConfig, colors: dict[str, np.ndarray]) -> LabMap:
    x, y = pixel_centres(cfg.width, cfg.height)
    lo, hi = cfg.density
    density = lo + (hi - lo) * x / (x.max() + x.min())
    t = (y / (y.max() + y.min()))[..., None]
    ab = (1.0 - t) * colors["blue"] + t * colors["green"]
    return lab_from_parts(density, ab)


def make_points(cfg: DictConfig, out_dir: Path, name: str) -> None:
    """Synthesise ``out_dir/NAME_points.txt`` from ``out_dir/NAME.tif`` (the map as written, 16-bit quantised)."""
    lab_map = read_map(out_dir / f"{name}.tif")
    result = synthesize(lab_map, n=point_count(lab_map, cfg.points_per_ink), seed=cfg.seed, threads=cfg.threads)
    write_points(result.points, out_dir / f"{name}_points.txt")
    print(f"wrote {out_dir / name}_points.txt ({len(result.points)} points, {result.seconds:.1f} s)")


def main(overrides: list[str]) -> None:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose(config_name="examples", overrides=overrides)
    out_dir = Path(cfg.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    colors = resolve_colors(cfg.colors)
    for name, lab_map in (("logo", make_logo(cfg.logo, colors)), ("gradient", make_gradient(cfg.gradient, colors))):
        write_map(lab_map, out_dir / f"{name}.tif", bits=cfg.bits)
        write_preview(lab_map, out_dir / f"{name}_preview.png", scale=cfg.preview_scale)
        print(f"wrote {out_dir / name}.tif and {name}_preview.png ({lab_map.width}x{lab_map.height})")
    for name in cfg.points.maps:
        make_points(cfg.points, out_dir, name)


if __name__ == "__main__":
    main(sys.argv[1:])
