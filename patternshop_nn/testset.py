"""The frozen test set's inputs (docs/evaluation.md): pictures -> truth maps -> stipplings, with a manifest.

``python -m patternshop_nn.testset OUT_DIR [--points 20000]`` builds, deterministically:

* the pictures: scikit-learn's two sample photos (``sklearn.datasets.load_sample_images``:
  :data:`TEST_PICTURES`), never used for anything else;
* each picture's **truth**: density ``1 - L*/100`` of the photo (sRGB, D65), at the photo's
  resolution (``NAME.truth.npy``, float32 (H, W) in [0, 1]; the domain has its long side 1);
* its stipplings with about :data:`TEST_POINTS` points by each of :data:`TEST_METHODS`: the
  frozen stipplers (:data:`data_gen.stipplers.FROZEN_METHODS`, which training pairs refuse) and
  our synthesis at two seeds (uniform correlation, the ``blue`` preset), as point files
  ``NAME.METHOD.txt`` carrying their domain and true ``points_per_ink``;
* ``manifest.json``: every file's sha256, the sha256 of the picture's pixels, counts, scales, seeds.

Nothing here scores anything: the figures are computed once per shipped model, by the protocol of
docs/evaluation.md, and only then.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from data_gen.provenance import file_sha256 as sha256_file
from data_gen.stipplers import FROZEN_METHODS
from synthesis.conventions import full_ink_points
from synthesis.labmap import LabMap
from synthesis.points import PointSet, write_points

TEST_PICTURES = ("china.jpg", "flower.jpg")  # sklearn.datasets.load_sample_images().filenames, by base name
TEST_POINTS = 20_000
SYNTHESIS_SEEDS = (0, 1)
SYNTHESIS_PRESET = "blue"
TEST_METHODS = (*sorted(FROZEN_METHODS), *(f"synthesis_seed{seed}" for seed in SYNTHESIS_SEEDS))
STIPPLE_SEED = 0  # the frozen stipplers' random stream (capacity_voronoi's start)
FORMAT = 1


def frozen_pictures() -> dict[str, np.ndarray]:
    """{name without suffix: (H, W, 3) uint8} of scikit-learn's two sample photos, in :data:`TEST_PICTURES` order."""
    from sklearn.datasets import load_sample_images

    bunch = load_sample_images()
    by_name = {Path(name).name: image for name, image in zip(bunch.filenames, bunch.images, strict=True)}
    return {Path(name).stem: np.asarray(by_name[name], np.uint8) for name in TEST_PICTURES}


def truth_density(rgb: np.ndarray) -> tuple[np.ndarray, tuple[float, float]]:
    """(density 1 - L*/100 (H, W) float32 in [0, 1] of an sRGB uint8 picture, its domain (long side 1))."""
    rgb = np.asarray(rgb)
    image = rgb.astype(np.float64) / 255.0
    image = np.repeat(image[..., None], 3, axis=-1) if image.ndim == 2 else image[..., :3]
    density = np.clip(1.0 - LabMap.from_srgb(image).L / 100.0, 0.0, 1.0).astype(np.float32)
    height, width = density.shape
    return density, (width / max(height, width), height / max(height, width))


def stipple(method: str, density: np.ndarray, domain: tuple[float, float], n: int,
            synthesis_iterations: int | None = None) -> np.ndarray:
    """(k, 2) points of ``method`` (one of :data:`TEST_METHODS`) on ``density``, about n of them, deterministic."""
    if method in FROZEN_METHODS:
        return FROZEN_METHODS[method](np.asarray(density, np.float64), n, domain, np.random.default_rng(STIPPLE_SEED))
    if method.startswith("synthesis_seed"):
        from synthesis.palette import ab_to_latent, load_palette
        from synthesis.synthesize import synthesize

        palette = load_palette()
        latent = np.broadcast_to(ab_to_latent(np.array(palette.preset(SYNTHESIS_PRESET))), (*density.shape, 2))
        lab_map = LabMap.from_density_latent(np.asarray(density, np.float64), np.array(latent, np.float64))
        result = synthesize(lab_map, n=n, palette=palette, iterations=synthesis_iterations,
                            seed=int(method.removeprefix("synthesis_seed")))
        return np.asarray(result.points.xy, np.float64)
    raise ValueError(f"unknown test-set method {method!r}; the test set uses {', '.join(TEST_METHODS)}")


def build_test_set(out_dir: str | Path, pictures: Mapping[str, np.ndarray] | None = None, n: int = TEST_POINTS,
                   methods: Sequence[str] = TEST_METHODS, synthesis_iterations: int | None = None) -> dict:
    """Write the test set's truth maps, point files and manifest into ``out_dir``; returns the manifest.

    ``pictures``: {name: sRGB uint8 picture}; default :func:`frozen_pictures` (the frozen photos). Other
    pictures, methods, counts or iterations are for tests of this code only: the manifest records them.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pictures = frozen_pictures() if pictures is None else pictures
    entries = []
    for name, rgb in pictures.items():
        density, domain = truth_density(rgb)
        truth_path = out / f"{name}.truth.npy"
        np.save(truth_path, density)
        picture = {"picture": name, "pixels_sha256": hashlib.sha256(np.ascontiguousarray(rgb).tobytes()).hexdigest(),
                   "shape": list(density.shape), "domain": [round(domain[0], 9), round(domain[1], 9)],
                   "truth": truth_path.name, "truth_sha256": sha256_file(truth_path), "stipplings": []}
        for method in methods:
            xy = stipple(method, density, domain, n, synthesis_iterations)
            scale = len(xy) / full_ink_points(float(np.mean(density)), domain)  # points per unit area of full ink
            path = out / f"{name}.{method}.txt"
            write_points(PointSet(np.asarray(xy, np.float64), domain, points_per_ink=scale), path)
            picture["stipplings"].append({"method": method, "file": path.name, "n": len(xy),
                                          "points_per_ink": round(scale, 3), "sha256": sha256_file(path)})
        entries.append(picture)
    manifest = {"format": FORMAT, "requested_points": n, "methods": list(methods), "stipple_seed": STIPPLE_SEED,
                "synthesis": {"preset": SYNTHESIS_PRESET, "seeds": list(SYNTHESIS_SEEDS), "iterations": synthesis_iterations},
                "pictures": entries}
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return manifest


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m patternshop_nn.testset", description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", help="folder for the truth maps, point files and manifest.json")
    parser.add_argument("--points", type=int, default=TEST_POINTS, help=f"points per stippling (default {TEST_POINTS})")
    args = parser.parse_args(argv)
    manifest = build_test_set(args.out_dir, n=args.points)
    print(json.dumps({"out_dir": args.out_dir, "files": sum(len(p["stipplings"]) + 1 for p in manifest["pictures"])}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
