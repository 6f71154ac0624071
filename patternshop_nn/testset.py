"""The frozen test set (docs/evaluation.md): its inputs (pictures -> truth maps -> stipplings, a manifest), and its scorer.

``python -m patternshop_nn.testset build OUT_DIR [--points 20000]`` builds, deterministically:

* the pictures: scikit-learn's two sample photos (``sklearn.datasets.load_sample_images``:
  :data:`TEST_PICTURES`), never used for anything else;
* each picture's **truth**: density ``1 - L*/100`` of the photo (sRGB, D65), at the photo's
  resolution (``NAME.truth.npy``, float32 (H, W) in [0, 1]; the domain has its long side 1);
* its stipplings with about :data:`TEST_POINTS` points by each of :data:`TEST_METHODS`: the
  frozen stipplers (:data:`data_gen.stipplers.FROZEN_METHODS`, which training pairs refuse) and
  our synthesis at two seeds (uniform correlation, the ``blue`` preset), as point files
  ``NAME.METHOD.txt`` carrying their domain and true ``points_per_ink``;
* ``manifest.json``: every file's sha256, the sha256 of the picture's pixels, counts, scales, seeds.

``python -m patternshop_nn.testset score SET_DIR [--model MODEL.onnx] --out RESULT_DIR`` scores a model on a
built set, by docs/evaluation.md's "How a case is scored", once per shipped model and only then: it refuses a set
whose files differ from ``manifest.json``; runs ``patternshop infer`` on each point file as a user does (default
settings, the header's domain and ``points_per_ink``); scores the map's L against the truth area-resampled to the
map (:func:`patternshop_nn.ood.l_scores`) beside the oracle and one-spacing KDEs of the same points; and writes
``score.json``, ``score.md`` (the "Report" table, counts against the targets, commit, sha256s), the inferred maps
(``maps/``) and a contact sheet per picture (``NAME.sheet.png``: truth | model | oracle KDE, in L).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from data_gen.provenance import file_sha256 as sha256_file
from data_gen.provenance import git_commit, utc_now
from data_gen.stipplers import FROZEN_METHODS
from export.runtime import DEFAULT_MODEL
from patternshop_nn.ood import contact_sheet, grey, kde_L, kde_scores, l_scores, resample
from synthesis.conventions import full_ink_points
from synthesis.errors import PatternshopError, run_module_cli
from synthesis.labmap import LabMap
from synthesis.mapio import read_map
from synthesis.points import PointSet, read_points, write_points

TEST_PICTURES = ("china.jpg", "flower.jpg")  # sklearn.datasets.load_sample_images().filenames, by base name
TEST_POINTS = 20_000
SYNTHESIS_SEEDS = (0, 1)
SYNTHESIS_PRESET = "blue"
TEST_METHODS = (*sorted(FROZEN_METHODS), *(f"synthesis_seed{seed}" for seed in SYNTHESIS_SEEDS))
STIPPLE_SEED = 0  # the frozen stipplers' random stream (capacity_voronoi's start)
FORMAT = 1
ORACLE_WIN_SHARE = 0.85  # targets (docs/evaluation.md): won against the oracle KDE in >= 85 % of cases (7 of 8),
MAX_SSIM_LOSS = 0.03  # no case lost to it by more than this SSIM, and every case won against the one-spacing KDE


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


class ScoreError(PatternshopError):
    """A test set that cannot be scored: files that differ from its manifest, a missing model, a failed ``infer``."""


def verified_manifest(set_dir: str | Path) -> tuple[dict, str]:
    """(manifest, sha256 of manifest.json) of a built set, after checking every file it lists against its sha256.

    Raises:
        ScoreError: no readable manifest, another format, or a file missing or not the one the manifest names.
    """
    folder = Path(set_dir)
    path = folder / "manifest.json"
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ScoreError(f"{path}: no readable test-set manifest ({type(exc).__name__})") from None
    if manifest.get("format") != FORMAT:
        raise ScoreError(f"{path}: test-set format {manifest.get('format')!r}, this scorer reads {FORMAT}")
    try:
        listed = [(p["truth"], p["truth_sha256"]) for p in manifest["pictures"]]
        listed += [(s["file"], s["sha256"]) for p in manifest["pictures"] for s in p["stipplings"]]
    except (KeyError, TypeError) as exc:
        raise ScoreError(f"{path}: not a test-set manifest (no {exc})") from None
    differ = [name for name, digest in listed if not (folder / name).is_file() or sha256_file(folder / name) != digest]
    if differ:
        raise ScoreError(f"{folder}: {len(differ)} of {len(listed)} files missing or not as manifest.json records "
                           f"({', '.join(differ)}): refusing to score")
    return manifest, sha256_file(path)


def infer_as_a_user(points_path: Path, model: Path, map_path: Path) -> tuple[LabMap, list[str]]:
    """(the map ``patternshop infer POINTS MAP --model MODEL`` writes, default settings otherwise; its stderr lines)."""
    command = [sys.executable, "-m", "patternshop", "infer", str(points_path), str(map_path), "--model", str(model)]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    messages = done.stderr.strip().splitlines()
    if done.returncode != 0:
        raise ScoreError(f"patternshop infer failed on {points_path.name}: {messages[-1] if messages else done.returncode}")
    return read_map(map_path), messages


def one_spacing_px(domain: tuple[float, float], n: int, shape: tuple[int, int]) -> float:
    """The one-spacing KDE's bandwidth: one mean point spacing sqrt(w h / n) (domain units) in pixels of a map (H, W)."""
    return math.sqrt(domain[0] * domain[1] / n) * max(shape)


def won(ssim: float, mae: float, baseline_ssim: float, baseline_mae: float) -> bool:
    """A case is won against a baseline when the model's SSIM is higher and its MAE lower (both strictly)."""
    return ssim > baseline_ssim and mae < baseline_mae


def score_case(folder: Path, picture: dict, stippling: dict, model: Path, maps: Path) -> tuple[dict, list[np.ndarray]]:
    """(the case's row, [truth, model, oracle KDE at its SSIM bandwidth] L previews) for one point file of a set.

    Figures are rounded as reported (SSIM 4 decimals, MAE 3: :func:`patternshop_nn.ood.kde_scores`'s) and won or
    lost is decided on the reported figures, so that the table shows why.
    """
    points = read_points(folder / stippling["file"])
    if points.points_per_ink is None:
        raise ScoreError(f"{stippling['file']}: no points_per_ink in its header")
    lab_map, messages = infer_as_a_user(folder / stippling["file"], model, maps / f"{Path(stippling['file']).stem}.tif")
    L = lab_map.L.astype(np.float64)
    truth_L = 100.0 * (1.0 - resample(np.load(folder / picture["truth"]), L.shape))
    ssim, mae = (round(value, digits) for value, digits in zip(l_scores(truth_L, L), (4, 3), strict=True))
    oracle = kde_scores(points.xy, truth_L, points.points_per_ink)
    spacing = one_spacing_px(points.domain, len(points.xy), L.shape)
    one_ssim, one_mae = l_scores(truth_L, kde_L(points.xy, L.shape, points.points_per_ink, spacing))
    row = {"picture": picture["picture"], "method": stippling["method"], "n": len(points.xy),
           "points_per_ink": points.points_per_ink, "map_shape": list(L.shape), "ssim": ssim, "mae": mae,
           "oracle_ssim": oracle["kde_ssim"], "oracle_ssim_bandwidth_px": oracle["kde_ssim_bandwidth_px"],
           "oracle_mae": oracle["kde_mae"], "oracle_mae_bandwidth_px": oracle["kde_mae_bandwidth_px"],
           "one_spacing_bandwidth_px": round(spacing, 3), "one_spacing_ssim": round(one_ssim, 4),
           "one_spacing_mae": round(one_mae, 3)}
    row["won_oracle"] = won(ssim, mae, row["oracle_ssim"], row["oracle_mae"])
    row["won_one_spacing"] = won(ssim, mae, row["one_spacing_ssim"], row["one_spacing_mae"])
    row["ssim_loss_to_oracle"] = round(max(0.0, row["oracle_ssim"] - ssim), 4)
    row["infer_messages"] = messages
    oracle_L = kde_L(points.xy, L.shape, points.points_per_ink, oracle["kde_ssim_bandwidth_px"])
    return row, [grey(truth_L), grey(L), grey(oracle_L)]


def score_targets(rows: Sequence[dict]) -> list[dict]:
    """The frozen-set targets of docs/evaluation.md on scored rows: (figure, target, measured, met)."""
    n = len(rows)
    need = math.ceil(ORACLE_WIN_SHARE * n - 1e-9)
    oracle_wins = sum(r["won_oracle"] for r in rows)
    loss = max((r["ssim_loss_to_oracle"] for r in rows), default=0.0)
    spacing_wins = sum(r["won_one_spacing"] for r in rows)
    return [{"figure": "cases won against the oracle KDE (SSIM higher and MAE lower)",
             "target": f">= {need} of {n} ({100 * ORACLE_WIN_SHARE:.0f} %)", "measured": f"{oracle_wins} of {n}",
             "met": oracle_wins >= need},
            {"figure": "largest SSIM loss to the oracle KDE", "target": f"<= {MAX_SSIM_LOSS}", "measured": loss,
             "met": loss <= MAX_SSIM_LOSS},
            {"figure": "cases won against the one-spacing KDE", "target": f"{n} of {n}", "measured": f"{spacing_wins} of {n}",
             "met": spacing_wins == n}]


def is_frozen(manifest: dict) -> bool:
    """Whether a manifest is the frozen set's (its pictures, methods, point count and default synthesis), not a stand-in."""
    return ([p["picture"] for p in manifest["pictures"]] == [Path(name).stem for name in TEST_PICTURES]
            and manifest["methods"] == list(TEST_METHODS) and manifest["requested_points"] == TEST_POINTS
            and manifest["synthesis"]["iterations"] is None)


def score_test_set(set_dir: str | Path, model: str | Path, out_dir: str | Path) -> dict:
    """Score ``model`` on the built set in ``set_dir``; writes score.json, score.md, maps/ and the contact sheets.

    Raises:
        ScoreError: the set's files differ from its manifest, the model is missing, or ``infer`` fails.
    """
    folder, model, out = Path(set_dir), Path(model), Path(out_dir)
    manifest, manifest_sha256 = verified_manifest(folder)
    if not model.is_file():
        raise ScoreError(f"{model}: no such model file")
    (out / "maps").mkdir(parents=True, exist_ok=True)
    rows, sheets = [], {}
    for picture in manifest["pictures"]:
        sheet = []
        for stippling in picture["stipplings"]:
            print(f"scoring {stippling['file']}", file=sys.stderr)
            row, previews = score_case(folder, picture, stippling, model, out / "maps")
            rows.append(row)
            sheet.append((f"{stippling['method']}\ntruth | model |\noracle KDE {row['oracle_ssim_bandwidth_px']:g} px", previews))
        sheets[picture["picture"]] = sheet
    results = {"set_dir": str(folder), "frozen": is_frozen(manifest), "manifest_sha256": manifest_sha256,
               "model": str(model), "model_sha256": sha256_file(model), "commit": git_commit(), "scored_at": utc_now(),
               "cases": rows, "targets": score_targets(rows)}
    for name, sheet in sheets.items():
        contact_sheet(sheet, out / f"{name}.sheet.png", tile=max(max(r["map_shape"]) for r in rows))
    (out / "score.json").write_text(json.dumps(results, indent=1) + "\n")
    (out / "score.md").write_text(score_markdown(results))
    return results


def score_markdown(results: dict) -> str:
    """docs/evaluation.md's "Report": the table of the cases, the counts against the targets, commit and sha256s."""
    lines = [f"# Frozen test set: {Path(results['model']).name}", ""]
    if not results["frozen"]:
        lines += ["**Not the frozen test set** (other pictures, methods, point count or synthesis iterations): "
                  "a check of the scorer, no figure of the model.", ""]
    lines += [f"- model: `{results['model']}`, sha256 `{results['model_sha256']}`",
              f"- test set: `{results['set_dir']}`, manifest.json sha256 `{results['manifest_sha256']}`",
              f"- commit: `{results['commit']}`; scored {results['scored_at']}",
              "- model: `patternshop infer` with its default settings; KDEs of the same points at the same "
              "points per ink; oracle bandwidths (map px) chosen with the truth, for SSIM and for MAE apart; "
              "won = SSIM higher and MAE lower, on the figures shown", "",
              "| picture | stippling | n | model SSIM | model MAE | oracle SSIM (px) | oracle MAE (px) "
              "| one-spacing SSIM | one-spacing MAE (px) | vs oracle | vs one-spacing |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['picture']} | {r['method']} | {r['n']} | {r['ssim']:.4f} | {r['mae']:.3f} "
              f"| {r['oracle_ssim']:.4f} ({r['oracle_ssim_bandwidth_px']:g}) | {r['oracle_mae']:.3f} ({r['oracle_mae_bandwidth_px']:g}) "
              f"| {r['one_spacing_ssim']:.4f} | {r['one_spacing_mae']:.3f} ({r['one_spacing_bandwidth_px']:.2f}) "
              f"| {'won' if r['won_oracle'] else 'lost'} | {'won' if r['won_one_spacing'] else 'lost'} |"
              for r in results["cases"]]
    lines += ["", "| target | wanted | measured | met |", "|---|---|---|---|"]
    lines += [f"| {t['figure']} | {t['target']} | {t['measured']} | {'yes' if t['met'] else 'no'} |" for t in results["targets"]]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m patternshop_nn.testset", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    build = commands.add_parser("build", help="build the frozen test set's inputs (the frozen photos; the lead only)")
    build.add_argument("out_dir", help="folder for the truth maps, point files and manifest.json")
    build.add_argument("--points", type=int, default=TEST_POINTS, help=f"points per stippling (default {TEST_POINTS})")
    score = commands.add_parser("score", help="score a model on a built set (once per shipped model)")
    score.add_argument("set_dir", help="a folder written by build")
    score.add_argument("--model", default=str(DEFAULT_MODEL), help="ONNX model (default: the shipped default.onnx)")
    score.add_argument("--out", required=True, help="folder for score.json, score.md, maps/ and the contact sheets")

    def run(args: argparse.Namespace) -> None:
        if args.command == "build":
            manifest = build_test_set(args.out_dir, n=args.points)
            print(json.dumps({"out_dir": args.out_dir, "files": sum(len(p["stipplings"]) + 1 for p in manifest["pictures"])}))
            return
        results = score_test_set(args.set_dir, args.model, args.out)
        print(json.dumps({"out": args.out, "cases": len(results["cases"]),
                          "targets_met": all(t["met"] for t in results["targets"])}))

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
