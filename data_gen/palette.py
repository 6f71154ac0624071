"""Build the correlation palette: ``python -m data_gen.palette [key=value ...]``.

Stages (SPEC §2.1, paper §4): corpus (random spectra realised as points,
minus those whose fit stacked points; plus the parametric families of
:mod:`data_gen.families`, from the perfect lattice to large clusters; PCFs and
perceptual features; cached, resumable, parallel) -> L1 dissimilarities of the
features (log-compressed, ``embedding.compression``) -> metric MDS ->
PCA-reduced features -> presets (each takes over its perceptually
nearest exemplar) -> orientation (white noise at a = b = 0, blue noise on a
blue hue, clusters on red, green noise on green, the pinned regular exemplars
on blue hues; one scale, and the least hue warp of ``embedding.warps`` that
leaves no 60-degree hue wedge with more than ``max_wedge_share`` of the
exemplars) -> PCF table (:func:`data_gen.palette_table.with_preset_exemplars`:
PCFs re-measured, presets realised exactly, 256 x 256 IDW look-up table) ->
quality metrics (decoding reads the exemplars' PCFs, :func:`synthesis.palette.pcf_code`;
:func:`data_gen.palette_table.decoding_record`). Writes the asset (``output``), a provenance record beside
it (same name, ``.json``) and the exemplars' nearest-neighbour bounds (:func:`data_gen.palette_table.write_neighbour_table`). Settings: ``conf/palette.yaml``; tiny variant
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
from data_gen.executor import Executor
from data_gen.families import build_families
from data_gen.provenance import git_commit, machine, run_config_command, utc_now, versions
from data_gen.embedding import compressed, l1_distances, mds_layout, orient, stress1, trustworthiness
from data_gen.palette_table import decoding_record, with_preset_exemplars, write_neighbour_table
from synthesis.atomic import atomic_write_text
from synthesis.features import block_slices, scale_blocks
from synthesis.palette import Palette, ab_to_latent, hue_chroma, latent_to_ab
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


STACKED_DISTANCE = 0.05  # r_max: a point this close to another is stacked on it


def stacked_share(points: np.ndarray) -> np.ndarray:
    """(N,) share of each toroidal pattern's points (N, P, 2) stacked on another (nearest neighbour < 0.05 r_max)."""
    from synthesis.generators._torus import r_max, tree

    return np.array([np.mean(tree(p).query(p, k=2)[0][:, 1] < STACKED_DISTANCE * r_max(len(p))) for p in points])


def merged_corpus(cfg: DictConfig, config: CorpusConfig) -> tuple[dict[str, np.ndarray], dict]:
    """GMM exemplars whose fit stacked at most ``corpus.max_stacked_share`` of their points, then the families.

    Returns arrays ``points``, ``target``, ``pcf``, ``features``, ``family`` (``"gmm"`` or
    the family's name), ``label`` (``gmm#INDEX`` or :meth:`data_gen.families.FamilyExemplar.label`),
    ``gmm_index`` (index in the GMM corpus, -1 for families) and a record.
    """
    executor = Executor.from_config(cfg)
    corpus = build_corpus(config, cfg.cache_dir, executor)
    stacked = stacked_share(corpus["points"])
    keep = stacked <= cfg.corpus.max_stacked_share
    parts = [{"points": corpus["points"][keep], "target": corpus["target"][keep], "pcf": corpus["pcf"][keep],
              "features": corpus["features"][keep], "family": np.full(int(keep.sum()), "gmm"),
              "label": np.array([f"gmm#{index}" for index in np.flatnonzero(keep)]),
              "gmm_index": np.flatnonzero(keep)}]
    record = {"gmm_exemplars": config.exemplars, "gmm_dropped_stacked": int((~keep).sum()),
              "gmm_computed_now": int(corpus["computed_now"]), "gmm_worker_seconds": round(float(corpus["seconds"].sum()), 1),
              "gmm_fit_rms_median": round(float(np.median(corpus["fit_rms"][keep])), 4)}
    if cfg.families.enabled:
        families = build_families(config.points, cfg.seed, config.extractor, cfg.cache_dir, executor,
                                  stride=cfg.families.stride)
        parts.append({"points": families["points"], "target": families["target"], "pcf": families["pcf"],
                      "features": families["features"], "family": families["family"], "label": families["label"],
                      "gmm_index": np.full(len(families["points"]), -1)})
        names, counts = np.unique(families["family"], return_counts=True)
        record |= {"families": dict(zip(names.tolist(), counts.tolist())), "families_computed_now": int(families["computed_now"])}
    merged = {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}
    return merged, record


def largest_wedge_share(z: np.ndarray, degrees: float = 60.0) -> float:
    """Largest share of latents z (N, 2) whose hue falls in one ``degrees``-wide wedge (1-degree steps)."""
    ab = latent_to_ab(z)
    hue = np.degrees(np.arctan2(ab[:, 1], ab[:, 0])) % 360.0
    return max(float(np.mean((hue - start) % 360.0 < degrees)) for start in range(360))


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
    corpus, corpus_record = merged_corpus(cfg, config)
    lap("corpus")

    torch.set_num_threads(max(1, cfg.workers))
    weights = block_weights(corpus["features"])
    features = scale_blocks(corpus["features"], weights)
    dissimilarity = compressed(l1_distances(features), cfg.embedding.compression)  # what the layout embeds
    lap("dissimilarities")
    layout = mds_layout(dissimilarity, cfg.seed, cfg.embedding.mds_inits, cfg.embedding.mds_max_iter)
    lap("mds")

    mean, components, codes, explained = pca(features, cfg.embedding.pca_components, cfg.seed)
    extractor = FeatureExtractor(cfg.features.name, cfg.features.seed, cfg.features.weights)

    preset_exemplar: dict[str, int] = {}
    for name in cfg.presets.names:  # each preset takes over its nearest exemplar not taken by another
        code = (scale_blocks(extractor(generate(name, config.points, cfg.presets.seed), (1.0, 1.0), True), weights) - mean) @ components.T
        distance = np.sum((codes - code) ** 2, axis=1)
        distance[list(preset_exemplar.values())] = np.inf
        preset_exemplar[name] = int(np.argmin(distance))
    hues = {name: float(h) for name, h in cfg.embedding.hues.items() if name in preset_exemplar}
    anchors = {name: layout[preset_exemplar[name]] for name in list(hues) + [cfg.embedding.centre] if name in preset_exemplar}
    labels = corpus["label"].tolist()
    for pin in cfg.embedding.pins:  # family exemplars pinned to hues of their own (present in the corpus only)
        if pin.exemplar in labels:
            anchors[pin.exemplar], hues[pin.exemplar] = layout[labels.index(pin.exemplar)], float(pin.hue)
    orientations = []
    for warp in cfg.embedding.warps:  # the least warp that spreads the exemplars over the hues
        z, transform = orient(layout, anchors, hues, centre=cfg.embedding.centre, warp=float(warp),
                              fill_quantile=cfg.embedding.fill_quantile, pin=cfg.embedding.pin_hues)
        transform |= {"largest_wedge_share": round(largest_wedge_share(z), 3), "stress1": round(stress1(dissimilarity, z), 4),
                      "trustworthiness": round(trustworthiness(dissimilarity, z, cfg.metrics.trust_k), 4)}
        orientations.append((z, transform))
        print(f"[palette] warp {warp}: {transform}", file=sys.stderr, flush=True)
        if transform["largest_wedge_share"] <= cfg.embedding.max_wedge_share:
            break
    z, transform = orientations[-1]
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
    neighbours = write_neighbour_table(output)  # the nearest-neighbour term's bounds, beside the asset
    lap("save")

    # --- quality metrics ---------------------------------------------------
    rng = np.random.default_rng([cfg.seed, 999])
    gmm = np.flatnonzero(corpus["gmm_index"] >= 0)
    holdout = rng.choice(gmm, size=min(cfg.metrics.holdout, len(gmm)), replace=False)
    spectrum = RadialSpectrum(config.points, config.spectrum.bins)
    errors = []
    for index in holdout:  # an independent realisation of a GMM exemplar's spectrum, decoded
        fit = fit_spectrum(corpus["target"][index], config.points, np.random.default_rng([cfg.seed, 7, int(corpus["gmm_index"][index])]),
                           config.fit_iterations, config.fit_learning_rate, spectrum)
        decoded = palette.locate(fit.points, periodic=True)
        errors.append(float(np.linalg.norm(ab_to_latent([decoded.a, decoded.b]) - z[index])))
    errors = np.array(errors)
    preset_z = {name: z[index] for name, index in preset_exemplar.items()}
    separations = {f"{p}-{q}": round(float(np.linalg.norm(preset_z[p] - preset_z[q])), 3)
                   for i, p in enumerate(preset_z) for q in list(preset_z)[i + 1 :]}
    metrics = {
        "exemplars": len(z),
        "dissimilarity": "L1" if cfg.embedding.compression is None else f"log(1 + L1 / ({cfg.embedding.compression} median))",
        "stress1": round(stress1(dissimilarity, layout), 4),  # the MDS layout
        "trustworthiness_k": cfg.metrics.trust_k,
        "trustworthiness": round(trustworthiness(dissimilarity, layout, cfg.metrics.trust_k), 4),
        "stress1_final": transform["stress1"],  # the palette's latents (after orientation)
        "trustworthiness_final": transform["trustworthiness"],
        "largest_wedge_share": transform["largest_wedge_share"],
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
        "corpus": corpus_record,  # *_computed_now: the rest came from cache_dir
        "corpus_exemplars_computed": corpus_record["gmm_computed_now"] + corpus_record.get("families_computed_now", 0),
        "extractor": extractor.describe(),
        "orientation": transform,
        "orientations_tried": [record for _, record in orientations],
        "presets": presets,
        "metrics": metrics,
        "decoding": decoding_record(palette),
        "neighbours": neighbours,
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
