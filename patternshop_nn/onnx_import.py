"""A trainable generator rebuilt from an exported ONNX model, to fine-tune a model whose checkpoint is gone.

``python -m patternshop_nn.onnx_import MODEL.onnx OUT.ckpt --pairs PAIR_DIR [--l-scale]`` writes a checkpoint that
``train.py init_from=OUT.ckpt`` starts from (the shipped model v5 exists only as ``default.onnx``).

The exporter (:mod:`patternshop_nn.onnx_export`) changed the weights' form but not the function, so each layer is
read back and inverted:

* the encoder's convolution + batch norm pairs were folded by the ONNX exporter into one convolution (weight ``Wf``,
  bias ``bf``): the convolution takes ``Wf``, the batch norm ``gamma = s``, ``beta = bf + m``, running mean ``m`` and
  variance ``s^2`` (minus its eps), where ``m``, ``s`` are the per-channel mean and standard deviation of ``Wf * x`` on
  calibration rasters (``rasters``; without them 0 and 1). The function in eval mode is exactly the exported one either
  way; with the statistics, training mode's batch statistics give about the same function too;
* every fused up-sampling convolution (:class:`patternshop_nn.networks.NearestUpConv`, four 2x2 phase kernels, 16
  sums of the 9 taps of the 3x3 kernel) is solved back to its 3x3 kernel by least squares (exact: the sums are
  consistent), its bias is every fourth of the exported one;
* the decoders' batch norms and the other convolutions (the full-resolution path's included, where the model has
  one: ``model.full_res_channels``, its stride read from its first convolution) are copied.

With ``l_scale=True`` the generator gets the Laplace-scale head: the exported one where the model has it (its
``l_scale`` output; such models name their layers ``generator.*``), else initialised as new layers are
(:func:`patternshop_nn.networks.init_weights`) with its bias such that the scale starts at about ``initial_scale``.
The discriminator is not exported: it starts fresh.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch
from torch import nn

from patternshop_nn.networks import L_SCALE_MIN, DualBranchUNet, init_weights
from synthesis.errors import PatternshopError, run_module_cli

INITIAL_SCALE = 0.05  # the new l_scale head's starting scale (L/100): about the shipped model's held-out density MAE


def _taps_matrix() -> np.ndarray:
    """(16, 9) matrix taking a 3x3 kernel (row-major) to NearestUpConv's four 2x2 phase kernels (phase-major, row-major)."""
    groups = ([[0], [1, 2]], [[0, 1], [2]])  # rows (or columns) of the 3x3 kernel summed into each 2x2 tap, by phase
    matrix = np.zeros((16, 9))
    for phase_row in (0, 1):
        for phase_col in (0, 1):
            for r in (0, 1):
                for c in (0, 1):
                    out = (2 * phase_row + phase_col) * 4 + 2 * r + c
                    for i in groups[phase_row][r]:
                        for j in groups[phase_col][c]:
                            matrix[out, 3 * i + j] = 1.0
    return matrix


def unfuse_kernel(weight: np.ndarray) -> np.ndarray:
    """(Cout, Cin, 3, 3) kernel whose :class:`~patternshop_nn.networks.NearestUpConv` weights are ``weight`` (4 Cout, Cin, 2, 2)."""
    cout4, cin = weight.shape[:2]
    phases = weight.reshape(cout4 // 4, 4, cin, 4).transpose(0, 2, 1, 3).reshape(cout4 // 4, cin, 16)
    taps = phases @ np.linalg.pinv(_taps_matrix()).T  # (Cout, Cin, 9)
    return taps.reshape(cout4 // 4, cin, 3, 3)


def _onnx_layers(path: Path) -> tuple[dict[str, np.ndarray], list[tuple[str, str | None]]]:
    """(initialisers by name, (weight, bias) names of the Conv nodes in graph order)."""
    import onnx
    from onnx import numpy_helper

    try:
        model = onnx.load(str(path))
    except Exception as exc:  # onnx raises DecodeError and others for a file that is not a model
        raise PatternshopError(f"{path}: not a readable ONNX model ({type(exc).__name__})") from exc
    arrays = {_layer_name(init.name): numpy_helper.to_array(init) for init in model.graph.initializer}
    for node in model.graph.node:  # the exporter shares equal initialisers through Identity nodes (and folds constants)
        if node.op_type == "Identity" and _layer_name(node.input[0]) in arrays:
            arrays[_layer_name(node.output[0])] = arrays[_layer_name(node.input[0])]
        elif node.op_type == "Constant" and node.attribute and node.attribute[0].name == "value":
            arrays[_layer_name(node.output[0])] = numpy_helper.to_array(node.attribute[0].t)
    convs = [(_layer_name(node.input[1]), _layer_name(node.input[2]) if len(node.input) > 2 else None)
             for node in model.graph.node if node.op_type == "Conv"]
    return arrays, convs


def _layer_name(name: str) -> str:
    """An initialiser's name as the generator's state dict spells it: models exported with the uncertainty head
    (:class:`~patternshop_nn.networks.WithScale`) prefix every layer with ``generator.``."""
    return name.removeprefix("generator.")


def _encoder_state(convs: list[tuple[str, str | None]], arrays: dict[str, np.ndarray], state: dict[str, torch.Tensor],
                   root: str, eps: float, first_level: int = 0) -> dict[str, torch.Tensor]:
    """The state of one encoder (names under ``root``: "" or "correlation_encoder.") from its exported convolutions in
    order, the first of level ``first_level`` (an own encoder after shared levels); a batch norm folded into a
    convolution comes back with identity statistics and the folded bias as its shift (:func:`calibrate_folded_norms`
    refines them)."""
    new = {}
    for k, (weight, bias) in enumerate(convs, start=first_level):
        prefix = f"{root}first" if k == 0 else f"{root}downs.{k - 1}.1"
        new[f"{prefix}.weight"] = torch.from_numpy(arrays[weight].copy())
        if f"{prefix}.bias" in state:  # no batch norm after it: copied as is
            new[f"{prefix}.bias"] = torch.from_numpy(arrays[bias].copy())
        else:
            norm, channels = f"{root}downs.{k - 1}.2", arrays[weight].shape[0]
            new.update({f"{norm}.weight": torch.ones(channels), f"{norm}.bias": torch.from_numpy(arrays[bias].copy()),
                        f"{norm}.running_mean": torch.zeros(channels), f"{norm}.running_var": torch.full((channels,), 1.0 - eps)})
    return new


def generator_from_onnx(path: str | Path, levels: int = 6, base_channels: int = 12, max_channels: int = 96,
                        l_scale: bool = False, initial_scale: float = INITIAL_SCALE) -> DualBranchUNet:
    """A nearest-upsampling :class:`DualBranchUNet` whose eval-mode function is the exported model's (see module docstring);
    it has the model's full-resolution path where the model has one.

    Raises:
        PatternshopError: the file is not an exported generator of this architecture.
    """
    path = Path(path)
    arrays, convs = _onnx_layers(path)
    path_width, path_stride = 0, 1
    if "full_res.0.weight" in arrays:  # (C, k * k, 3, 3): C channels on the raster's k x k blocks
        path_width, path_stride = arrays["full_res.0.weight"].shape[0], math.isqrt(arrays["full_res.0.weight"].shape[1])
    # the correlation decoder's own encoder (its last level keeps its name), traced after the shared one
    own_encoder = any(name.startswith("correlation_encoder.") for name in arrays)
    encoders = [(w, b) for w, b in convs if not w.startswith(("density.", "correlation.", "scale.", *DualBranchUNet.FULL_RES_MODULES))]
    shared_levels = 2 * levels - len(encoders) if own_encoder else 0  # the own encoder's levels: those past the shared ones
    new: dict[str, torch.Tensor] = {}
    ups = {branch: sum(f"{branch}.ups.{k}.1.weight" in arrays for k in range(levels)) for branch in ("density", "correlation")}
    coarse = arrays.get("correlation.head.1.weight", np.zeros((0, 0, 2, 2))).shape[-1] == 3  # a plain 3x3 head: it stops early
    correlation_stride = 2 ** (levels - ups["correlation"]) if coarse else 1
    try:
        if len(encoders) not in (range(levels + 1, 2 * levels + 1) if own_encoder else (levels,)):
            raise KeyError(f"{len(encoders)} encoder convolutions for {levels} levels")
        generator = DualBranchUNet(1, levels, base_channels, max_channels, 0.0, "nearest", l_scale, int(path_width),
                                   path_stride, own_encoder, shared_levels, correlation_stride).eval()
        init_weights(generator)
        state = generator.state_dict()
        eps = generator.downs[0][2].eps
        new.update(_encoder_state(encoders[:levels], arrays, state, "", eps))
        if own_encoder:
            new.update(_encoder_state(encoders[levels:], arrays, state, "correlation_encoder.", eps, shared_levels))
        for branch in ("density", "correlation"):
            for k in range(ups[branch]):
                for field in ("weight", "bias", "running_mean", "running_var"):
                    new[f"{branch}.ups.{k}.3.{field}"] = torch.from_numpy(arrays[f"{branch}.ups.{k}.3.{field}"].copy())
                new[f"{branch}.ups.{k}.2.weight"] = torch.from_numpy(unfuse_kernel(arrays[f"{branch}.ups.{k}.1.weight"]).astype(np.float32))
            if branch == "correlation" and coarse:  # a plain convolution, copied
                new.update({f"correlation.head.1.{field}": torch.from_numpy(arrays[f"correlation.head.1.{field}"].copy())
                            for field in ("weight", "bias")})
                continue
            new[f"{branch}.head.2.weight"] = torch.from_numpy(unfuse_kernel(arrays[f"{branch}.head.1.weight"]).astype(np.float32))
            new[f"{branch}.head.2.bias"] = torch.from_numpy(arrays[f"{branch}.head.1.bias"][::4].copy())
        new.update({name: torch.from_numpy(arrays[name].copy()) for name in state
                    if name.startswith(DualBranchUNet.FULL_RES_MODULES)})  # plain convolutions, copied
        if l_scale and "scale.1.weight" in arrays:  # the exported head, unfused as the other heads
            new["scale.2.weight"] = torch.from_numpy(unfuse_kernel(arrays["scale.1.weight"]).astype(np.float32))
            new["scale.2.bias"] = torch.from_numpy(arrays["scale.1.bias"][::4].copy())
        elif l_scale:  # a new head: its initial weights, a bias at softplus^-1 of the starting scale
            new.update({name: value for name, value in state.items() if name.startswith("scale.")})
            new["scale.2.bias"] = torch.full((1,), float(np.log(np.expm1(initial_scale - L_SCALE_MIN))))
        generator.load_state_dict(new, strict=True)
    except (KeyError, RuntimeError, ValueError) as exc:
        reason = str(exc).strip().splitlines()[0][:200]
        raise PatternshopError(f"{path}: not an exported generator with levels={levels}, base_channels={base_channels}, "
                               f"max_channels={max_channels} and nearest up-sampling ({reason})") from exc
    return generator


def calibrate_folded_norms(generator: DualBranchUNet, rasters: torch.Tensor) -> None:
    """Give the folded batch norms (those with identity statistics) the statistics of their input on ``rasters``
    (B, 1, S, S) without changing the eval-mode function (module docstring)."""
    encoders = [generator, *([generator.correlation_encoder] if generator.correlation_encoder is not None else [])]
    norms = [down[2] for encoder in encoders for down in encoder.downs
             if isinstance(down, nn.Sequential) and len(down) > 2 and isinstance(down[2], nn.BatchNorm2d)]
    folded = [norm for norm in norms if torch.all(norm.weight == 1) and torch.all(norm.running_mean == 0)]
    captured: dict[int, torch.Tensor] = {}
    hooks = [norm.register_forward_hook(lambda module, inputs, output, key=id(norm): captured.__setitem__(key, inputs[0]))
             for norm in folded]
    try:
        with torch.no_grad():
            generator.eval()(rasters)
    finally:
        for hook in hooks:
            hook.remove()
    with torch.no_grad():
        for norm in folded:
            values = captured[id(norm)]
            mean, std = values.mean(dim=(0, 2, 3)), values.std(dim=(0, 2, 3)).clamp_min(1e-3)
            norm.running_mean.copy_(mean)
            norm.running_var.copy_(std**2 - norm.eps)
            norm.weight.copy_(std)
            norm.bias.add_(mean)


def checkpoint_from_onnx(onnx_path: str | Path, out_path: str | Path, rasters: torch.Tensor | None = None,
                         **model_kwargs: object) -> Path:
    """Write a checkpoint for ``train.py init_from=`` (a :class:`~patternshop_nn.module.Pix2PixModule` state dict with the
    rebuilt generator and a fresh discriminator); ``model_kwargs`` are the module's (levels, base_channels,
    max_channels, l_scale ...; upsample is "nearest")."""
    from patternshop_nn.module import Pix2PixModule, save_module_checkpoint

    module = Pix2PixModule(**{**model_kwargs, "upsample": "nearest"})
    hp = module.hparams
    generator = generator_from_onnx(onnx_path, hp.levels, hp.base_channels, hp.max_channels, module.generator.l_scale)
    own_encoder = generator.correlation_encoder is not None
    if generator.full_res_channels or own_encoder or generator.correlation.stride > 1:  # the module (and its hparams) take the export's layers
        shared_levels = generator.correlation_encoder.shared_levels if own_encoder else 0
        module = Pix2PixModule(**{**model_kwargs, "upsample": "nearest", "full_res_channels": generator.full_res_channels,
                                  "full_res_stride": generator.full_res_stride, "correlation_encoder": own_encoder,
                                  "correlation_shared_levels": shared_levels,
                                  "correlation_stride": generator.correlation.stride})
    if rasters is not None:
        calibrate_folded_norms(generator, rasters)
    module.generator.load_state_dict(generator.state_dict())
    return save_module_checkpoint(module, out_path, rebuilt_from_onnx=str(onnx_path))


def main(argv: list[str] | None = None) -> int:
    """Command line: see module docstring; errors are one line on stderr (exit 2)."""
    parser = argparse.ArgumentParser(prog="python -m patternshop_nn.onnx_import", description=__doc__.splitlines()[0])
    parser.add_argument("model", help="exported .onnx generator")
    parser.add_argument("out", help="checkpoint to write")
    parser.add_argument("--pairs", help="pair folder whose first rasters calibrate the folded batch norms")
    parser.add_argument("--calibration-items", type=int, default=64)
    parser.add_argument("--l-scale", action="store_true",
                        help="give the generator the uncertainty head (Laplace scale of L): the model's own if it has one, else a new one")
    parser.add_argument("--l-nll-weight", type=float, default=1.0)

    def run(args: argparse.Namespace) -> None:
        rasters = None
        if args.pairs:
            from data_gen.shards import load_pairs

            pairs = load_pairs(args.pairs)
            rasters = torch.from_numpy(pairs.raster[: args.calibration_items].astype(np.float32))[:, None]
        print(checkpoint_from_onnx(args.model, args.out, rasters, l_scale=args.l_scale, l_nll_weight=args.l_nll_weight))

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
