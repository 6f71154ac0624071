"""Build the correlation palette: ``python -m data_gen.palette [key=value ...]``.

Stages (SPEC §2.1, paper §4): corpus (random spectra realised as points, their
PCFs and perceptual features; cached, resumable, parallel) -> L1
dissimilarities -> metric MDS -> orientation (blue noise on a blue hue) ->
IDW look-up table -> PCA-reduced features for decoding -> presets -> quality
metrics. Writes the asset (``output``) and a provenance record beside it
(same name, ``.json``). Settings: ``conf/palette.yaml``; tiny variant
``--config-name palette_small``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from data_gen.corpus import CorpusConfig, SpectrumRanges, build_corpus
from data_gen.provenance import git_commit, machine, run_config_command, utc_now, versions
from data_gen.embedding import l1_distances, mds_layout, orient, stress1, trustworthiness
from data_gen.palette_table import with_preset_exemplars
from synthesis.atomic import atomic_write_text
from synthesis.features import block_slices, scale_blocks
from synthesis.palette import Palette, hue_chroma, latent_to_ab
from synthesis.pcf import pcf_radii

def corpus_config(cfg: DictConfig) -> CorpusConfig:
    spectrum = SpectrumRanges(**{k: tuple(v) if not isinstance(v, int) else v for k, v in cfg.corpus.spectrum.items()})
    from synthesis.features import FEATURES_VERSION

    extractor = tuple((k, cfg.features[k]) for k in ("name", "seed", "weights")) + (("version", FEATURES_VERSION),)
    return CorpusConfig(
        exemplars=cfg.corpus.exemplars, points=cfg.corpus.points, seed=cfg.seed, spectrum=spectrum,
        fit_iterations=cfg.corpus.fit_iterations, fit_learning_rate=cfg.corpus.fit_learning_rate,
        chunk=cfg.corpus.chunk, extractor=extractor,
    )


def block_weights(features: np.ndarray) -> np.ndarray:
    """(6,) weights giving every Gram block (layer x splat size) the same mean L1 norm."""
    norms = np.array([np.abs(features[:, block]).sum(axis=1).mean() for block in block_slices()])
    return (norms.mean() / np.maximum(norms, 1e-12)).astype(np.float32)


def pca(features: np.ndarray, components: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(mean (D,), components (k, D), codes (N, k), explained variance fraction)."""
    from sklearn.decomposition import PCA

    model = PCA(n_components=min(components, len(features) - 1), svd_solver="randomized", random_state=seed)
    codes = model.fit_transform(features)
    return model.mean_.astype(np.float32), model.components_.astype(np.float32), codes.astype(np.float32), float(model.explained_variance_ratio_.sum())


def build(cfg: DictConfig) -> dict:
    """Run every stage; returns the provenance record (also written beside the asset)."""
    import torch

    from synthesis.features import FeatureExtractor
    from synthesis.generators import generate
    from synthesis.spectrum import RadialSpectrum, fit_spectrum

    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[stage] = round(now - clock, 2)
        clock = now
        print(f"[palette] {stage}: {timings[stage]:.1f} s", file=sys.stderr, flush=True)

    config = corpus_config(cfg)
    corpus = build_corpus(config, cfg.cache_dir, cfg.workers)
    lap("corpus")

    torch.set_num_threads(max(1, cfg.workers))
    weights = block_weights(corpus["features"])
    features = scale_blocks(corpus["features"], weights)
    dissimilarity = l1_distances(features)
    lap("dissimilarities")
    layout = mds_layout(dissimilarity, cfg.seed, cfg.embedding.mds_inits, cfg.embedding.mds_max_iter)
    lap("mds")

    mean, components, codes, explained = pca(features, cfg.embedding.pca_components, cfg.seed)
    extractor = FeatureExtractor(cfg.features.name, cfg.features.seed, cfg.features.weights)

    def nearest(points: np.ndarray, periodic: bool = True) -> int:
        code = (scale_blocks(extractor(points, (1.0, 1.0), periodic), weights) - mean) @ components.T
        return int(np.argmin(np.sum((codes - code) ** 2, axis=1)))

    preset_points = {name: generate(name, config.points, cfg.presets.seed) for name in cfg.presets.names}
    preset_exemplar = {name: nearest(points) for name, points in preset_points.items()}
    hues = {name: float(h) for name, h in cfg.embedding.hues.items() if name in preset_exemplar}
    anchors = {name: layout[preset_exemplar[name]] for name in hues}
    z, transform = orient(layout, anchors, hues)
    lap("presets and orientation")

    presets = {}
    for name, index in preset_exemplar.items():
        a, b = latent_to_ab(z[index])
        hue, chroma = hue_chroma(a, b)
        presets[name] = {"a": round(float(a), 2), "b": round(float(b), 2), "hue": round(hue, 1), "chroma": round(chroma, 1),
                         "exemplar": index, "generator": f"synthesis.generators.{name}"}
    unfinished = Palette(
        radii=pcf_radii(), lut=np.empty((0, 0, 0), np.float32), exemplar_z=z, exemplar_pcf=corpus["pcf"].astype(np.float32),
        exemplar_points=corpus["points"], exemplar_spectrum=corpus["target"], exemplar_dispersion=np.empty((0, 0), np.float32),
        dispersion_lut=np.empty((0, 0, 0), np.float32), codes=codes, feature_mean=mean, components=components,
        block_scale=weights, presets=presets, extractor=extractor.describe(),
    )
    # PCFs and dispersions measured with the current estimator, presets made exemplars of their generators, tables
    palette, _ = with_preset_exemplars(unfinished, config.points, lambda s: print(s, file=sys.stderr, flush=True))
    z, presets = palette.exemplar_z, palette.presets
    lap("look-up table")
    output = Path(cfg.output)
    output.parent.mkdir(parents=True, exist_ok=True)
    palette.save(output)
    lap("save")

    # --- quality metrics ---------------------------------------------------
    rng = np.random.default_rng([cfg.seed, 999])
    holdout = rng.choice(config.exemplars, size=min(cfg.metrics.holdout, config.exemplars), replace=False)
    spectrum = RadialSpectrum(config.points, config.spectrum.bins)
    errors = []
    for index in holdout:
        fit = fit_spectrum(corpus["target"][index], config.points, np.random.default_rng([cfg.seed, 7, int(index)]),
                           config.fit_iterations, config.fit_learning_rate, spectrum)
        errors.append(float(np.linalg.norm(z[nearest(fit.points)] - z[index])))
    errors = np.array(errors)
    preset_z = {name: z[index] for name, index in preset_exemplar.items()}
    separations = {f"{p}-{q}": round(float(np.linalg.norm(preset_z[p] - preset_z[q])), 3)
                   for i, p in enumerate(preset_z) for q in list(preset_z)[i + 1 :]}
    metrics = {
        "stress1": round(stress1(dissimilarity, layout), 4),
        "trustworthiness_k": cfg.metrics.trust_k,
        "trustworthiness": round(trustworthiness(dissimilarity, layout, cfg.metrics.trust_k), 4),
        "fit_rms_median": round(float(np.median(corpus["fit_rms"])), 4),
        "fit_rms_p90": round(float(np.percentile(corpus["fit_rms"], 90)), 4),
        "pca_explained_variance": round(explained, 4),
        "decode_holdout": len(holdout),
        "decode_within_0.05": round(float(np.mean(errors <= 0.05)), 3),
        "decode_error_median": round(float(np.median(errors)), 4),
        "preset_min_separation": round(min(separations.values()), 3) if separations else None,
        "preset_separations": separations,
    }
    lap("metrics")
    timings["total"] = round(sum(timings.values()), 2)
    record = {
        "asset": output.name,
        "command": "python -m data_gen.palette " + " ".join(sys.argv[1:]),
        "config": OmegaConf.to_container(cfg, resolve=True),
        "corpus_key": config.key(),
        "corpus_exemplars_computed": int(corpus["computed_now"]),  # the rest came from cache_dir
        "corpus_worker_seconds": round(float(corpus["seconds"].sum()), 1),  # realise + measure, all exemplars
        "extractor": extractor.describe(),
        "orientation": transform,
        "presets": presets,
        "metrics": metrics,
        "timings_s": timings,
        "versions": versions(),
        "commit": git_commit(),
        "built": utc_now(),
        "machine": machine(),
        "asset_bytes": output.stat().st_size,
    }
    atomic_write_text(output.with_suffix(".json"), json.dumps(record, indent=2) + "\n")
    return record


def _build_and_report(cfg) -> dict:  # noqa: ANN001 - omegaconf.DictConfig
    record = build(cfg)
    return {"metrics": record["metrics"], "presets": record["presets"], "timings_s": record["timings_s"]}


def main(argv: list[str] | None = None) -> int:
    """Parse Hydra overrides (``--config-name NAME`` picks another config) and build."""
    return run_config_command("python -m data_gen.palette", "palette", __doc__, _build_and_report, argv)


if __name__ == "__main__":
    sys.exit(main())
