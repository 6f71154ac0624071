"""The palette's PCF table in the estimator's terms, with every preset realised exactly.

``python -m data_gen.palette_table [--palette IN] [--output OUT]`` rebuilds the
PCF side of a palette asset without touching its layout (the exemplars' latent
coordinates and perceptual codes): it re-measures every exemplar's PCF with the
current estimator (:func:`synthesis.pcf.stationary_pcf`) and its count
dispersion (:func:`synthesis.pcf.count_dispersion`, the synthesiser's noise model), makes each named
preset an exemplar of its own generator (points, perceptual code and the
generator's PCF averaged over several realisations, placed on the 8-bit
colour grid node nearest to the preset's colour in the input palette, so that painting the
preset's 8-bit colour asks for exactly that generator's PCF), and recomputes
the 256 x 256 IDW look-up table (and a 64 x 64 one of the dispersion). The full build (:mod:`data_gen.palette`) uses
the same functions. A provenance record goes into the asset's ``.json``
(section ``table``), with one of the decoding (section ``decoding``, :func:`decoding_record`: decoding reads the
exemplars' PCFs, so it has no table of its own). ``--decoding-only`` writes only that section and leaves the asset
(and its sha256, which trained models record) untouched.

Every rebuild also writes the exemplars' nearest-neighbour bounds beside the asset (``palette_neighbours.npz``,
:func:`write_neighbour_table`; section ``neighbours`` of the record), which the synthesiser's nearest-neighbour term
reads instead of measuring them at start-up (2 ms per exemplar: 2-2.5 s for a map using every colour);
``--neighbours-only`` writes only that table and its section, the asset untouched.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from synthesis.palette import (DECODE_BIN_WIDTH, DECODE_NEIGHBOURS, DECODE_POWER, DEFAULT_PALETTE, DISPERSION_LUT_SIZE, LUT_SIZE,
                               NEIGHBOUR_QUANTILES, Palette, ab_to_latent, exemplar_neighbour_bounds, hue_chroma,
                               latent_to_ab, neighbour_table_path)
from synthesis.errors import run_module_cli
from synthesis.pcf import count_dispersion, pcf_radii, stationary_pcf

PRESET_POINTS = 4096  # generator realisations measured per preset ...
PRESET_REALISATIONS = 6  # ... and how many, averaged
PRESET_SEED = 1234
KDE_WINDOW = 0.01  # IDW locality (SPEC §2.1)
LOCALITY = (3.0, 6.0)


def exemplar_statistics(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, m) PCFs and (N, m) count dispersions of N toroidal exemplar point sets (N, P, 2) in [0, 1)^2."""
    pcf = np.stack([stationary_pcf(p, periodic=True) for p in points])
    dispersion = np.stack([count_dispersion(p, periodic=True) for p in points])
    return pcf.astype(np.float32), dispersion.astype(np.float32)


def generator_statistics(name: str, n: int = PRESET_POINTS, realisations: int = PRESET_REALISATIONS,
                         seed: int = PRESET_SEED) -> tuple[np.ndarray, np.ndarray]:
    """(m,) mean PCF and (m,) mean count dispersion of ``realisations`` toroidal patterns of generator ``name`` (n points)."""
    from synthesis.generators import generate

    patterns = [generate(name, n, seed + i) for i in range(realisations)]
    return (np.mean([stationary_pcf(p, periodic=True) for p in patterns], axis=0),
            np.mean([count_dispersion(p, periodic=True) for p in patterns], axis=0))


def snap_to_grid(z: np.ndarray) -> np.ndarray:
    """Latent z (..., 2) moved to the nearest 8-bit colour node (integer a, b)."""
    return ab_to_latent(np.rint(latent_to_ab(z)))


def look_up_table(z: np.ndarray, values: np.ndarray, size: int = LUT_SIZE) -> np.ndarray:
    """(size, size, m) IDW table (paper eq. 4) of exemplar values (N, m) at latents z (N, 2); nodes at (i, j) / (size - 1)."""
    from data_gen.embedding import idw_encode, kde_locality

    grid = np.stack(np.meshgrid(np.arange(size), np.arange(size), indexing="ij"), axis=-1).reshape(-1, 2) / (size - 1)
    power = kde_locality(grid, z, KDE_WINDOW, *LOCALITY)
    return idw_encode(grid, z, values, power).reshape(size, size, -1).astype(np.float32)


def with_preset_exemplars(palette: Palette, exemplar_points_count: int, log=print) -> tuple[Palette, dict]:  # noqa: ANN001
    """The palette with each preset's exemplar replaced by its generator and the PCF table rebuilt.

    Returns the new palette and a record of what moved (per preset: old and new
    colour, the generator PCF's first radii).
    """
    z = palette.exemplar_z.copy()
    points = palette.exemplar_points.copy()
    codes = palette.codes.copy()
    start = time.perf_counter()
    pcf, dispersion = exemplar_statistics(points)
    log(f"[table] {len(points)} exemplar PCFs and dispersions measured: {time.perf_counter() - start:.1f} s")
    presets, record = {}, {}
    for name, preset in palette.presets.items():
        from synthesis.generators import generate

        index = int(preset["exemplar"])
        z[index] = snap_to_grid(z[index])
        points[index] = generate(name, exemplar_points_count, PRESET_SEED)
        pcf[index], dispersion[index] = generator_statistics(name)
        codes[index] = palette.reduce(palette._extractor(points[index], (1.0, 1.0), True))
        a, b = (float(v) for v in latent_to_ab(z[index]))
        hue, chroma = hue_chroma(a, b)
        presets[name] = {**preset, "a": round(a, 2), "b": round(b, 2), "hue": round(hue, 1), "chroma": round(chroma, 1)}
        record[name] = {"old_ab": [preset["a"], preset["b"]], "ab": [round(a), round(b)],
                        "pcf_first_radii": [round(float(v), 3) for v in pcf[index][:10]]}
        log(f"[table] preset {name}: exemplar {index} -> generator at ({a:.0f}, {b:.0f})")
    start = time.perf_counter()
    lut = look_up_table(z, pcf)
    dispersion_lut = look_up_table(z, dispersion, DISPERSION_LUT_SIZE)
    log(f"[table] look-up tables: {time.perf_counter() - start:.1f} s")
    new = Palette(radii=pcf_radii(), lut=lut, exemplar_z=z, exemplar_pcf=pcf, exemplar_points=points,
                  exemplar_spectrum=palette.exemplar_spectrum, exemplar_dispersion=dispersion,
                  dispersion_lut=dispersion_lut, codes=codes, feature_mean=palette.feature_mean,
                  components=palette.components, block_scale=palette.block_scale, presets=presets,
                  extractor=palette.extractor)
    return new, record


def decoding_record(palette: Palette) -> dict:
    """How the palette decodes a pattern and how well it agrees with its layout: every exemplar decoded from the
    others (leave one out), distance to its own colour in ab units."""
    start = time.perf_counter()
    ab = latent_to_ab(palette.exemplar_z)
    decoded = [palette.locate_code(code, exclude=i) for i, code in enumerate(palette.pcf_codes)]
    errors = np.hypot([d.a for d in decoded] - ab[:, 0], [d.b for d in decoded] - ab[:, 1])
    return {"features": f"exemplar_pcf coarse-grained to {DECODE_BIN_WIDTH} r_max bins (synthesis.palette.pcf_code)",
            "neighbours": DECODE_NEIGHBOURS, "power": DECODE_POWER,
            "leave_one_out_ab_median": round(float(np.median(errors)), 2), "leave_one_out_ab_p90": round(float(np.percentile(errors, 90)), 2),
            "seconds": round(time.perf_counter() - start, 2)}


def write_neighbour_table(asset: Path) -> dict:
    """Measure every exemplar's nearest-neighbour bounds (:func:`synthesis.palette.exemplar_neighbour_bounds`) of the
    palette asset at ``asset`` and write them beside it (:func:`synthesis.palette.neighbour_table_path`: (N, 2) float32
    ``bounds``, the ``quantiles`` and the CRC-32 of the stored exemplar points they were measured from); returns
    the record of the provenance's ``neighbours`` section."""
    import zipfile

    from synthesis.atomic import atomic_path

    start = time.perf_counter()
    palette = Palette.load(asset)
    bounds = np.array([exemplar_neighbour_bounds(points) for points in palette.exemplar_points], np.float32)
    with zipfile.ZipFile(asset) as archive:
        crc = archive.getinfo("exemplar_points.npy").CRC
    path = neighbour_table_path(asset)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            np.savez_compressed(handle, bounds=bounds, quantiles=np.array(NEIGHBOUR_QUANTILES), points_crc32=np.int64(crc))
    return {"table": path.name, "quantiles": list(NEIGHBOUR_QUANTILES), "exemplar_points_crc32": crc,
            "lower_range": [round(float(v), 4) for v in (bounds[:, 0].min(), bounds[:, 0].max())],
            "upper_range": [round(float(v), 4) for v in (bounds[:, 1].min(), bounds[:, 1].max())],
            "seconds": round(time.perf_counter() - start, 2)}


def main(argv: list[str] | None = None) -> int:
    """Rebuild the PCF table of a palette asset (default: the shipped one, in place)."""
    parser = argparse.ArgumentParser(prog="python -m data_gen.palette_table", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--palette", default=str(DEFAULT_PALETTE), help="palette asset to read (default: the shipped one)")
    parser.add_argument("--output", help="asset to write (default: the input, replaced atomically)")
    parser.add_argument("--decoding-only", action="store_true",
                        help="only record the decoding section in the input's provenance; the asset is not rewritten")
    parser.add_argument("--neighbours-only", action="store_true",
                        help="only write the nearest-neighbour bounds table beside the input and its provenance section; "
                             "the asset is not rewritten")

    def run(args: argparse.Namespace) -> None:
        from data_gen.provenance import git_commit, utc_now
        from synthesis.atomic import atomic_write_text

        only = args.decoding_only or args.neighbours_only
        palette = Palette.load(args.palette, layout_only=not only)
        command = "python -m data_gen.palette_table " + " ".join(argv if argv is not None else sys.argv[1:])
        output, sections = Path(args.palette), {}
        if not only:
            start = time.perf_counter()
            palette, record = with_preset_exemplars(palette, palette.exemplar_points.shape[1], lambda s: print(s, file=sys.stderr))
            output = Path(args.output or args.palette)
            palette.save(output)
            sections = {"presets": palette.presets, "table": {
                "command": command,
                "radii": [round(float(r), 3) for r in palette.radii], "estimator": "tent bins (synthesis.pcf), periodic",
                "preset_points": PRESET_POINTS, "preset_realisations": PRESET_REALISATIONS, "preset_seed": PRESET_SEED,
                "presets": record, "seconds": round(time.perf_counter() - start, 1), "commit": git_commit(), "built": utc_now(),
            }, "asset_bytes": output.stat().st_size}
        if not args.neighbours_only:
            sections["decoding"] = {**decoding_record(palette), "command": command, "commit": git_commit(), "built": utc_now()}
        if not args.decoding_only:
            sections["neighbours"] = {**write_neighbour_table(output), "command": command, "commit": git_commit(),
                                      "built": utc_now()}
        provenance_path = output.with_suffix(".json")
        provenance = json.loads(provenance_path.read_text()) if provenance_path.is_file() else {}
        atomic_write_text(provenance_path, json.dumps(provenance | sections, indent=2) + "\n")
        print(f"[table] wrote {provenance_path}" + ("" if only else f" and {output} ({output.stat().st_size / 1e6:.1f} MB)"),
              file=sys.stderr)

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
