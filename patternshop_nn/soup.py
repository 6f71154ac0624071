"""Weight-space interpolation ("model soup", WiSE-FT) of two checkpoints of one lineage.

``python -m patternshop_nn.soup A.ckpt B.ckpt --alpha X OUT.ckpt`` writes (1 − X) · A + X · B of every float
tensor of the two ``Pix2PixModule`` state dicts (generator, discriminator and batch-norm running statistics alike;
integer buffers such as ``num_batches_tracked`` are B's) as a checkpoint that ``patternshop export`` and
``train.py init_from=`` accept. The two must have the same tensors, shapes and architecture; their training
hyper-parameters (learning rate, loss weights) may differ: B's are kept.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from synthesis.atomic import atomic_path
from synthesis.errors import PatternshopError, run_module_cli

# Pix2PixModule hyper-parameters that fix the tensors and the graph; the rest only steer training.
ARCHITECTURE_KEYS = ("levels", "base_channels", "max_channels", "upsample", "l_scale", "disc_channels", "disc_layers")


def interpolate_state_dicts(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor],
                            alpha: float) -> dict[str, torch.Tensor]:
    """(1 − alpha) · a + alpha · b for every floating-point tensor; non-float tensors are taken from b.

    Args:
        a, b: state dicts with the same keys and shapes (any shapes).
        alpha: weight of b, 0..1 (0 gives a, 1 gives b; values outside extrapolate and are refused).

    Returns:
        a new state dict in b's key order, each tensor of b's dtype (the arithmetic in that dtype too).

    Raises:
        PatternshopError: alpha outside [0, 1], or the keys or a tensor's shape differ.
    """
    if not 0.0 <= alpha <= 1.0:
        raise PatternshopError(f"alpha must lie in [0, 1], got {alpha}")
    if set(a) != set(b):
        only = sorted(set(a) ^ set(b))
        raise PatternshopError(f"the two state dicts have different tensors ({len(only)} in one only, e.g. {only[0]})")
    out = {}
    for key, tb in b.items():
        ta = a[key]
        if ta.shape != tb.shape:
            raise PatternshopError(f"{key}: shapes differ ({tuple(ta.shape)} against {tuple(tb.shape)})")
        if tb.is_floating_point():
            out[key] = (1.0 - alpha) * ta.to(tb.dtype) + alpha * tb  # in b's dtype, as the shipped v10 was made
        else:
            out[key] = tb.clone()
    return out


def _load(path: Path) -> dict:
    if not path.is_file():
        raise PatternshopError(f"{path}: no such checkpoint")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for a file that is not a checkpoint
        raise PatternshopError(f"{path}: not a checkpoint ({type(exc).__name__})") from exc
    if not isinstance(checkpoint, dict) or "state_dict" not in checkpoint or "hyper_parameters" not in checkpoint:
        raise PatternshopError(f"{path}: not a Pix2PixModule checkpoint (no state_dict or hyper_parameters)")
    return checkpoint


def soup_checkpoints(a_path: str | Path, b_path: str | Path, alpha: float, out_path: str | Path) -> Path:
    """Write the interpolated checkpoint of ``a_path`` and ``b_path`` (weight ``alpha`` on b) to ``out_path``.

    The result carries b's epoch, global step and hyper-parameters, the Lightning version of b (or of this
    install), and a ``soup`` record {"a", "b", "alpha"}; no optimiser states.

    Raises:
        PatternshopError: a file is missing or not a checkpoint, or the architectures, keys or shapes differ.
    """
    import lightning

    a_path, b_path, out_path = Path(a_path), Path(b_path), Path(out_path)
    ca, cb = _load(a_path), _load(b_path)
    ha, hb = dict(ca["hyper_parameters"]), dict(cb["hyper_parameters"])
    differ = [k for k in ARCHITECTURE_KEYS if ha.get(k) != hb.get(k)]
    if differ:
        k = differ[0]
        raise PatternshopError(f"architectures differ: {k} is {ha.get(k)!r} in {a_path} and {hb.get(k)!r} in {b_path}")
    mixed = interpolate_state_dicts(ca["state_dict"], cb["state_dict"], alpha)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out_path) as temporary:  # a failed or interrupted write leaves no half checkpoint
        torch.save({"pytorch-lightning_version": cb.get("pytorch-lightning_version", lightning.__version__),
                    "epoch": cb.get("epoch", 0), "global_step": cb.get("global_step", 0), "state_dict": mixed,
                    "hparams_name": cb.get("hparams_name", "kwargs"), "hyper_parameters": hb,
                    "soup": {"a": str(a_path), "b": str(b_path), "alpha": alpha}}, temporary)
    return out_path


def main(argv: list[str] | None = None) -> int:
    """Command line: see module docstring; errors are one line on stderr (exit 2)."""
    parser = argparse.ArgumentParser(prog="python -m patternshop_nn.soup", description=__doc__.splitlines()[0])
    parser.add_argument("a", help="checkpoint A (weight 1 - alpha)")
    parser.add_argument("b", help="checkpoint B (weight alpha; its hyper-parameters, epoch and step are kept)")
    parser.add_argument("out", help="checkpoint to write")
    parser.add_argument("--alpha", type=float, required=True, help="weight of B, 0..1")

    def run(args: argparse.Namespace) -> None:
        path = soup_checkpoints(args.a, args.b, args.alpha, args.out)
        print(f"wrote {path}: {1 - args.alpha:.3g} x {args.a} + {args.alpha:.3g} x {args.b}")

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
