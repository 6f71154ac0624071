"""An exported model quantized to int8 (ONNX Runtime static quantization), for a cheaper network pass.

``python -m patternshop_nn.quantize MODEL.onnx OUT.onnx --pairs DIR [DIR ...]`` writes ``OUT.onnx``: the same
graph, inputs, outputs and metadata as ``MODEL.onnx`` (:mod:`patternshop_nn.onnx_export`), its convolutions at
the coarser scales in int8 (QDQ format: weights per output channel in 7 bits, so that CPUs without VNNI, whose
8-bit products can saturate, give the same maps; activations per tensor; their ranges the min/max seen on
:data:`CALIBRATION_RASTERS` rasters of the training pairs). The convolutions whose output is a
quarter of the raster's side or finer (:func:`fine_convolutions`: the first two of the encoder, the last up-sampling
of each decoder, the heads) stay float: in int8 they saved 8 ms of a 704 px pass and doubled the error.
The metadata gains ``quantized`` (what was done, for the model card). ``OnnxModel`` and ``infer`` run it as any
model; the float model it came from is its reference (:func:`max_output_difference`).

Measured with the v9b network (1.1M parameters, ``l_scale``; docs/network.md, "Measurements"): a 704 px pass
106 -> 80 ms of one core; the maps of 12 development stipplings (1 and 2 symmetries) within 4.4 L units of the
float model's (mean 0.04-0.28), SSIM against the picture -0.0012..+0.0008.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from synthesis.atomic import atomic_path
from synthesis.errors import run_module_cli

CALIBRATION_RASTERS = 36  # rasters of the training pairs whose activation ranges set the int8 scales
FINE_FRACTION = 4  # convolutions whose output side is at least the raster's side / this stay float
PROBE_SIDE = 64  # raster side of the run that measures each convolution's output side (the smallest the U-Net takes)

PathLike = str | os.PathLike


def calibration_rasters(pairs_dirs: list[PathLike], count: int = CALIBRATION_RASTERS, seed: int = 0) -> list[np.ndarray]:
    """``count`` rasters (1, 1, S, S) float32 in [0, 1] drawn at random (``seed``) from the pair shards of ``pairs_dirs``.

    Raises:
        PatternshopError: a folder without pair shards.
    """
    from data_gen.shards import read_shard, require_shards

    shards = [shard for folder in pairs_dirs for shard in require_shards(folder)]
    rasters = np.concatenate([read_shard(path).raster for path in shards])
    chosen = np.random.default_rng(seed).choice(len(rasters), size=min(count, len(rasters)), replace=False)
    return [rasters[k].astype(np.float32)[None, None] for k in sorted(chosen)]


def fine_convolutions(model_path: PathLike, fraction: int = FINE_FRACTION) -> list[str]:
    """Names (sorted) of the Conv nodes of an exported model whose output side is at least the raster's side / ``fraction``
    (measured by one run on a :data:`PROBE_SIDE` px raster with every Conv output exposed)."""
    import onnx
    import onnxruntime

    model = onnx.load(str(model_path))
    convolutions = [node for node in model.graph.node if node.op_type == "Conv"]
    exposed = {node.output[0] for node in convolutions} - {output.name for output in model.graph.output}
    model.graph.output.extend(onnx.helper.make_tensor_value_info(name, onnx.TensorProto.FLOAT, None) for name in sorted(exposed))
    session = onnxruntime.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    names = [output.name for output in session.get_outputs()]
    shapes = dict(zip(names, (value.shape for value in session.run(names, {model.graph.input[0].name:
                                                                            np.zeros((1, 1, PROBE_SIDE, PROBE_SIDE), np.float32)})), strict=True))
    return sorted(node.name for node in convolutions if shapes[node.output[0]][-1] >= PROBE_SIDE // fraction)


def quantize_model(source: PathLike, target: PathLike, pairs_dirs: list[PathLike], count: int = CALIBRATION_RASTERS,
                   seed: int = 0) -> dict:
    """Write ``target``: ``source`` (an exported model) with its coarser convolutions in int8 (see the module
    docstring), atomically; returns the ``quantized`` metadata entry it adds.

    Raises:
        PatternshopError: ``source`` is not a Patternshop model, or a folder has no pair shards.
    """
    import onnx
    from onnxruntime.quantization import CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    from export.runtime import OnnxModel

    OnnxModel(source)  # a Patternshop model, or a one-line error
    rasters = calibration_rasters(pairs_dirs, count, seed)

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.rasters = iter(rasters)

        def get_next(self) -> dict | None:
            raster = next(self.rasters, None)
            return None if raster is None else {"raster": raster}

    with tempfile.TemporaryDirectory() as scratch, atomic_path(target) as tmp:
        prepared = Path(scratch) / "prepared.onnx"  # constants folded (biases become initializers), shapes inferred
        quant_pre_process(str(source), str(prepared), skip_symbolic_shape=True)
        kept_float = fine_convolutions(prepared)
        entry = {"format": "int8 QDQ", "weights": "per output channel, 7 bits", "calibration": "min/max",
                 "calibration_rasters": len(rasters), "calibration_pairs": [str(folder) for folder in pairs_dirs],
                 "seed": seed, "float_convolutions": kept_float}
        quantize_static(str(prepared), str(tmp), Reader(), quant_format=QuantFormat.QDQ, op_types_to_quantize=["Conv"],
                        per_channel=True, reduce_range=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                        nodes_to_exclude=kept_float, calibrate_method=CalibrationMethod.MinMax,
                        extra_options={"WeightSymmetric": True})
        model = onnx.load(str(tmp))
        props = {prop.key: prop.value for prop in model.metadata_props if not prop.key.startswith("onnx.")}
        onnx.helper.set_model_props(model, {**props, "quantized": json.dumps(entry)})
        onnx.save(model, str(tmp))
    return entry


def max_output_difference(reference: PathLike, quantized: PathLike, rasters: np.ndarray) -> float:
    """Largest |quantized - reference| over the outputs (map and ``l_scale``) for rasters (B, 1, H, W) in [0, 1]."""
    from export.runtime import OnnxModel

    return float(np.abs(OnnxModel(quantized).predict_outputs(rasters) - OnnxModel(reference).predict_outputs(rasters)).max())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m patternshop_nn.quantize", description=__doc__.split("\n\n")[0])
    parser.add_argument("model", type=Path, help="exported model (.onnx)")
    parser.add_argument("output", type=Path, help="the int8 model to write (.onnx)")
    parser.add_argument("--pairs", nargs="+", required=True, help="training-pair folders whose rasters calibrate it")
    parser.add_argument("--rasters", type=int, default=CALIBRATION_RASTERS, help=f"calibration rasters (default {CALIBRATION_RASTERS})")
    parser.add_argument("--seed", type=int, default=0, help="which rasters (default 0)")

    def run(args: argparse.Namespace) -> None:
        if args.rasters < 1:
            parser.error("--rasters must be at least 1")
        entry = quantize_model(args.model, args.output, args.pairs, args.rasters, args.seed)
        print(f"wrote {args.output}: {len(entry['float_convolutions'])} convolutions kept float, "
              f"calibrated on {entry['calibration_rasters']} rasters")

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
