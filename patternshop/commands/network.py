"""Network commands: ``infer`` (points -> map with ONNX Runtime) and ``export`` (checkpoint -> ONNX model)."""

from __future__ import annotations

import argparse
import json
import sys

from patternshop.commands import (add_threads_option, check_map_output, check_memory, check_output, check_point_file,
                                  non_negative_int, positive_float, positive_int)
from export.infer_config import DEFAULT_INFER, SYMMETRY_CHOICES
from synthesis.conventions import POINTS_PER_INK, POINTS_PER_INK_MEANING
from synthesis.resources import export_check_bytes, inference_bytes


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """Add ``infer`` and ``export``."""
    infer = subparsers.add_parser(
        "infer",
        parents=[common],
        help="infer the map (density and correlation) of a point pattern with the network",
        description="Run the points-to-map network (ONNX Runtime, CPU) on a point file and write its map: "
        "L from the local density, a,b from the local correlation. The pattern is read at the synthesiser's "
        "scale (--points-per-ink points per unit area of full ink, so 'synthesize' of the map gives back as many "
        "points; without --points-per-ink, the '# points_per_ink:' the file's header records (synthesize writes it into "
        ".txt files), else 50,000 unless the pattern is denser somewhere, then the scale at which its "
        "densest 1% reads as full ink: the chosen scale is printed) and rasterised so that its points per pixel match "
        f"the network's training, mirrored {DEFAULT_INFER.border_px} raster pixels beyond the domain's border. The ink is then scaled so that "
        "the map holds the pattern's point count (an empty pattern gives a white map), and L is smoothed as far as the "
        "model's predicted uncertainty of L (its 'l_scale' output) allows: wide in flat areas, not across edges; one "
        "network pass per symmetry, nothing more. A model without an l_scale output (older exports, models trained "
        "with l_scale=false) is read the same way but its L is not smoothed. "
        "A non-square domain lies on a square raster and the output is cropped back, so the map keeps the domain's "
        "aspect, 256 px on its long side unless --width is given.",
    )
    infer.add_argument("points", help="input points (.txt, .csv or .npy)")
    infer.add_argument("output", help="output map: CIELAB .tif, or NAME.L.png for three channel PNGs")
    infer.add_argument("--model", metavar="FILE", help="ONNX model (default: the shipped patternshop_nn/assets/default.onnx)")
    infer.add_argument("--bits", type=int, choices=(8, 16), default=16, help="bits per sample of a TIFF output (default 16)")
    infer.add_argument("--preview", metavar="PNG", help="also write an sRGB PNG preview of the map")
    infer.add_argument("--domain", nargs=2, type=float, metavar=("W", "H"),
                       help="domain [0,W]x[0,H] of the points, max(W,H)=1 (default: the file's '# domain:' comment, else 1 1)")
    infer.add_argument("--width", type=positive_int, metavar="PX", help="resample the map to this width (default: 256 px on the long side)")
    infer.add_argument("--points-per-ink", type=positive_float, metavar="N",
                       help=f"{POINTS_PER_INK_MEANING}, at the pattern's scale (default: the file header's "
                       f"'# points_per_ink:', else {POINTS_PER_INK} as synthesize, raised automatically for a pattern denser "
                       "than that)")
    infer.add_argument("--no-calibrate", action="store_true",
                       help="keep the network's L (default: ink scaled so that the map holds the pattern's point count; "
                       "implies --no-denoise)")
    infer.add_argument("--no-denoise", action="store_true",
                       help="keep L's fine detail even where it is only noise (default: L smoothed, from 1 px up to 1/16 of the "
                       "map, as far as the model's predicted uncertainty of L allows; a model without l_scale: never "
                       "smoothed)")
    infer.add_argument("--symmetries", type=int, choices=SYMMETRY_CHOICES,
                       help="average the network's readings over this many symmetries of the square, one network pass each: "
                       f"8 flips and transposes, 4 flips, 2, 1 a single run (default: {DEFAULT_INFER.symmetries})")
    infer.add_argument("--report", metavar="JSON", help="write a JSON report (points per ink chosen, ink factor, smoothing, ...)")
    add_threads_option(infer)
    infer.set_defaults(func=run_infer)

    export = subparsers.add_parser(
        "export",
        parents=[common],
        help="export a trained network checkpoint to an ONNX model for infer and convert",
        description="Export the generator of a training checkpoint (python train.py writes "
        "runs/NAME/checkpoints/best.ckpt and last.ckpt) to ONNX (opset 17, input 'raster' (B,1,H,W), output "
        "'map' (B,3,H,W), all axes dynamic, H and W multiples of 64), with metadata: palette, raster parameters and model-card "
        "fields. Prints the largest difference between torch and ONNX Runtime on random rasters.",
    )
    export.add_argument("checkpoint", help="Lightning checkpoint (.ckpt) of patternshop_nn.module.Pix2PixModule")
    export.add_argument("output", help="output .onnx")
    export.add_argument("--pairs", metavar="DIR", help="training-pair folder: records its dataset, points_per_ink and palette")
    export.add_argument("--name", help="model name for the model card")
    export.add_argument("--description", help="model description for the model card")
    export.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="another model-card field (VALUE is JSON if it parses, else text); repeatable")
    export.add_argument("--check", type=non_negative_int, default=2, metavar="N", help="random rasters for the torch/ONNX comparison (default 2)")
    add_threads_option(export)
    export.set_defaults(func=run_export)


def run_infer(args: argparse.Namespace) -> None:
    output = check_map_output(args.output, args.points)
    preview = check_output(args.preview, args.points, args.output, suffixes=(".png",)) if args.preview else None
    report_path = check_output(args.report, args.points, args.output, suffixes=(".json",)) if args.report else None
    check_point_file(args, args.points)

    from export.runtime import map_width, raster_scale
    from patternshop import api
    from synthesis.atomic import all_or_nothing, atomic_write_text
    from synthesis.mapio import write_map, write_preview

    model = api.load_model(args.model, threads=args.threads)
    points = api.read_points(args.points, domain=tuple(args.domain) if args.domain else None, allow_empty=True)
    scale = api.infer_scale(points, args.points_per_ink)
    (w, h), (_, side) = points.domain, raster_scale(points.domain, model.raster_size, model.points_per_ink, scale.points_per_ink)
    width = map_width(points.domain, model, args.width)
    check_memory(args, inference_bytes(side, width * max(1, round(width * h / w))),
                 f"inferring a {width} px wide map from a {side}x{side} px raster ({scale.points_per_ink:g} points per ink)")
    inference = api.infer(points, model=model, points_per_ink=scale, width=args.width,
                          calibrate=not args.no_calibrate, symmetries=args.symmetries, denoise=not args.no_denoise)
    report = {"points": args.points, "n": len(points), "model": str(model.path), "output": str(output), **inference.report()}
    with all_or_nothing():
        write_map(inference.lab_map, output, bits=args.bits)
        if preview is not None:
            write_preview(inference.lab_map, preview)
        if report_path is not None:
            atomic_write_text(report_path, json.dumps(report, indent=2) + "\n")
    lab_map = inference.lab_map
    print(f"wrote {output} ({lab_map.width}x{lab_map.height} px) from {len(points)} points with {model.path}", file=sys.stderr)
    keep = (f"; pass --points-per-ink {scale.points_per_ink:.0f} to synthesize to keep the point count"
            if scale.points_per_ink != POINTS_PER_INK else "")
    print(f"read at {scale.describe()}{keep}", file=sys.stderr)
    if inference.calibration is not None and len(points):
        print(f"ink scaled by {inference.calibration:.3g} to hold the {len(points)} points", file=sys.stderr)
    if inference.denoised_px > 0:
        print(f"L smoothed within the network's predicted uncertainty: {inference.denoised_px:.1f} px wide on average",
              file=sys.stderr)
    if not model.has_l_scale:
        print(f"note: {model.path} has no l_scale output (predicted uncertainty of L): its L is not smoothed", file=sys.stderr)


def _card_field(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` -> (key, JSON value or the text)."""
    from synthesis.errors import PatternshopError

    key, separator, value = text.partition("=")
    if not separator or not key:
        raise PatternshopError(f"--set needs KEY=VALUE, got {text!r}")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def run_export(args: argparse.Namespace) -> None:
    import numpy as np

    from data_gen.provenance import file_sha256
    from patternshop_nn.onnx_export import OPSET, export_onnx, load_generator, max_abs_difference, metadata_from_pairs
    from synthesis.raster import RASTER_SIZE

    output = check_output(args.output, args.checkpoint, suffixes=(".onnx",))
    check_memory(args, export_check_bytes(args.check, RASTER_SIZE),
                 f"the torch/ONNX comparison on {args.check} rasters (--check)")
    metadata = metadata_from_pairs(args.pairs) if args.pairs else {}
    metadata.update({key: value for key, value in (("name", args.name), ("description", args.description)) if value})
    metadata.update(_card_field(text) for text in args.set)
    generator = load_generator(args.checkpoint)
    metadata.update({"checkpoint": str(args.checkpoint), "checkpoint_sha256": file_sha256(args.checkpoint)})
    props = export_onnx(generator, output, metadata)
    message = f"wrote {output} (opset {OPSET}, {props['generator']['parameters']} parameters)"
    if args.check > 0:
        rasters = np.random.default_rng(0).random((args.check, 1, RASTER_SIZE, RASTER_SIZE), dtype=np.float32)
        message += f"; max |torch - onnxruntime| = {max_abs_difference(generator, output, rasters):.2g} on {args.check} random rasters"
    print(message, file=sys.stderr)
