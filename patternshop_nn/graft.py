"""Put one generator's correlation branch beside another's density: L from one checkpoint, a, b from another.

``python -m patternshop_nn.graft DENSITY.ckpt CORRELATION.ckpt OUT.ckpt``

A generator whose correlation decoder reads an encoder of its own (``correlation_encoder``, all levels its own:
``correlation_shared_levels`` 0, as :mod:`patternshop_nn.tune_encoder` makes it) computes a, b from the raster
alone: its correlation branch (``generator.correlation_encoder`` and ``generator.correlation``) never reads the
shared encoder, the density decoder, the full-resolution path or the ``l_scale`` head. So a density retrained
after the correlation branch was tuned (a new L stage, a distillation) can take that branch as it is: the
result's L and Laplace scale are DENSITY's and its a, b are CORRELATION's, bit for bit
(``tests/test_graft.py``). The written checkpoint (:func:`patternshop_nn.module.save_module_checkpoint`;
``patternshop export`` and ``init_from`` take it) has DENSITY's hyper-parameters with CORRELATION's branch keys,
and records both sources. Seconds; nothing is trained.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from synthesis.errors import PatternshopError, run_module_cli

if TYPE_CHECKING:  # importing the module pulls in Lightning
    from patternshop_nn.module import Pix2PixModule

BRANCH_KEYS = ("correlation_encoder", "correlation_shared_levels", "correlation_stride")  # hyper-parameters of the branch
BRANCH_MODULES = ("generator.correlation.", "generator.correlation_encoder.")  # its names in the state dict
ENCODER_KEYS = ("levels", "base_channels", "max_channels", "upsample")  # hyper-parameters the branch's shapes follow


def graft_correlation(density: Pix2PixModule, correlation: Pix2PixModule) -> Pix2PixModule:
    """A new module (eval mode): ``density``'s weights and hyper-parameters, its correlation branch replaced by
    ``correlation``'s (see the module docstring).

    Raises:
        PatternshopError: ``correlation`` has no encoder of its own, or shares levels with its density's encoder,
            or the two generators' encoder widths differ.
    """
    from patternshop_nn.module import Pix2PixModule

    branch = {key: correlation.hparams.get(key) for key in BRANCH_KEYS}
    if not branch["correlation_encoder"] or branch["correlation_shared_levels"]:
        raise PatternshopError("the correlation checkpoint's decoder must read an encoder all of its own "
                               "(correlation_encoder true, correlation_shared_levels 0; made by patternshop_nn.tune_encoder)")
    differ = [k for k in ENCODER_KEYS if density.hparams.get(k) != correlation.hparams.get(k)]
    if differ:
        key = differ[0]
        raise PatternshopError(f"the generators differ in {key} ({density.hparams.get(key)!r} against "
                               f"{correlation.hparams.get(key)!r}): the branch would not fit")
    grafted = Pix2PixModule(**{**density.hparams, **branch})
    state = {k: v for k, v in density.state_dict().items() if not k.startswith(BRANCH_MODULES)}
    state.update({k: v for k, v in correlation.state_dict().items() if k.startswith(BRANCH_MODULES)})
    grafted.load_state_dict(state, strict=True)
    return grafted.eval()


def main(argv: list[str] | None = None) -> int:
    """Command line: see module docstring; errors are one line on stderr (exit 2)."""
    parser = argparse.ArgumentParser(prog="python -m patternshop_nn.graft", description=__doc__.splitlines()[0])
    parser.add_argument("density", help="checkpoint whose L, Laplace scale and discriminator are kept")
    parser.add_argument("correlation", help="checkpoint whose correlation branch (own encoder and decoder) is taken")
    parser.add_argument("out", help="checkpoint to write")

    def run(args: argparse.Namespace) -> None:
        from patternshop_nn.module import save_module_checkpoint
        from patternshop_nn.onnx_export import load_module

        grafted = graft_correlation(load_module(args.density), load_module(args.correlation))
        save_module_checkpoint(grafted, args.out, grafted_from={"density": str(Path(args.density)),
                                                                 "correlation": str(Path(args.correlation))})
        print(f"wrote {args.out}: L from {args.density}, a, b from {args.correlation}")

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
