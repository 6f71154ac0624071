"""Contact sheet of training pairs: ``python -m data_gen.preview PAIR_DIR sheet.png``.

Each cell shows one pair: the target map's sRGB preview on the left and its
synthesised points, rendered as dots, on the right, with the item number
and point count underneath. Pairs are taken evenly across the folder.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from data_gen.shards import Pairs, load_pairs, target_to_map
from synthesis.atomic import atomic_path
from synthesis.errors import PatternshopError, run_module_cli
from synthesis.points import PointSet
from synthesis.render import dots_grey

GAP = 6  # pixels between cells and between a cell's two panels
LABEL_HEIGHT = 16


def pair_panels(pairs: Pairs, k: int, tile: int) -> tuple[np.ndarray, np.ndarray]:
    """(map preview, rendered points), each (tile, tile, 3) uint8, of pair k."""
    lab_map = target_to_map(pairs.target[k])
    preview = Image.fromarray(lab_map.to_srgb8()).resize((tile, tile), Image.Resampling.NEAREST)
    dots = dots_grey(PointSet(pairs.points_of(k).astype(np.float64), lab_map.domain), tile)
    return np.asarray(preview), np.repeat(dots[..., None], 3, axis=-1)


def contact_sheet(pairs: Pairs, count: int = 12, columns: int = 3, tile: int = 256) -> np.ndarray:
    """(H, W, 3) uint8 sheet of ``count`` pairs spread evenly over ``pairs``, ``columns`` pairs per row."""
    if len(pairs) == 0:
        raise PatternshopError("no pairs to show")
    chosen = np.unique(np.linspace(0, len(pairs) - 1, min(count, len(pairs))).round().astype(int))
    rows = -(-len(chosen) // columns)
    cell_w, cell_h = 2 * tile + GAP, tile + LABEL_HEIGHT
    sheet = Image.new("RGB", (columns * cell_w + (columns + 1) * GAP, rows * cell_h + (rows + 1) * GAP), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default(size=12)
    for slot, k in enumerate(chosen):
        x = GAP + (slot % columns) * (cell_w + GAP)
        y = GAP + (slot // columns) * (cell_h + GAP)
        preview, dots = pair_panels(pairs, int(k), tile)
        sheet.paste(Image.fromarray(preview), (x, y))
        sheet.paste(Image.fromarray(dots), (x + tile + GAP, y))
        draw.rectangle([x + tile + GAP, y, x + 2 * tile + GAP - 1, y + tile - 1], outline=(160, 160, 160))
        draw.text((x, y + tile + 2), f"item {int(pairs.item[k])}  n = {pairs.meta[k]['n']}", fill=(0, 0, 0), font=font)
    return np.asarray(sheet)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m data_gen.preview", description=__doc__.split("\n\n")[0],
                                     epilog="Example: python -m data_gen.preview data/pairs/procedural out/pairs.png --count 12")
    parser.add_argument("pair_dir", help="folder of pair shards (made by python -m data_gen.pairs)")
    parser.add_argument("output", help="PNG contact sheet to write")
    parser.add_argument("--count", type=int, default=12, help="pairs to show (default 12)")
    parser.add_argument("--columns", type=int, default=3, help="pairs per row (default 3)")
    parser.add_argument("--tile", type=int, default=256, help="panel size in pixels (default 256)")

    def run(args: argparse.Namespace) -> None:
        if args.count < 1 or args.columns < 1 or args.tile < 8:
            raise PatternshopError("--count and --columns must be >= 1 and --tile >= 8")
        output = Path(args.output)
        if output.suffix.lower() != ".png":
            raise PatternshopError(f"{output}: the contact sheet must be a .png")
        sheet = contact_sheet(load_pairs(args.pair_dir), args.count, args.columns, args.tile)
        with atomic_path(output) as tmp:
            Image.fromarray(sheet).save(tmp, format="PNG")
        print(f"wrote {args.output}")

    return run_module_cli(parser, run, argv)


if __name__ == "__main__":
    sys.exit(main())
