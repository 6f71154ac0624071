"""The palette picture: the ab plane as a grid of example patterns on their colours."""

from __future__ import annotations

import os

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from synthesis.atomic import atomic_path
from synthesis.labmap import LabMap
from synthesis.palette import Palette, ab_to_latent, latent_to_ab

SUPERSAMPLE = 3
POINTS_PER_CELL = 110
BACKGROUND_L = 88.0
MARGIN = 56
LUT_SIDE = 128  # resolution of the map behind the continuous palette


def _cell_colour(z: np.ndarray) -> tuple[int, int, int]:
    a, b = latent_to_ab(z)
    rgb = LabMap(np.array([[[BACKGROUND_L, a, b]]])).to_srgb()[0, 0]
    return tuple(int(round(255 * c)) for c in rgb)


def _draw_pattern(draw: ImageDraw.ImageDraw, points: np.ndarray, box: tuple[int, int, int], radius: float) -> None:
    """Points (n, 2) in [0, 1)^2 drawn into the square ``box`` = (left, top, side), in supersampled pixels."""
    left, top, side = box
    for x, y in points * side:
        cx, cy = left + x, top + y
        draw.ellipse((cx - radius, cy - radius, cx + radius, cy + radius), fill=(20, 20, 20))


def draw_palette(palette: Palette, path: str | os.PathLike, grid: int = 9, cell: int = 112) -> None:
    """Write the palette picture: ``grid`` x ``grid`` cells of ``cell`` pixels, presets marked.

    Cell columns run along a (left to right), rows along b (bottom to top). A
    cell shows the exemplar nearest to its centre, cropped to about
    :data:`POINTS_PER_CELL` points, on a light background of its colour; cells
    with no exemplar nearby show the colour alone (not covered by the corpus).
    """
    s = SUPERSAMPLE
    size = grid * cell
    image = Image.new("RGB", ((size + 2 * MARGIN) * s, (size + 2 * MARGIN) * s), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    window = np.sqrt(POINTS_PER_CELL / palette.exemplar_points.shape[1])
    radius = 0.2 * cell * s / np.sqrt(POINTS_PER_CELL)
    for col in range(grid):
        for row in range(grid):
            z = np.array([(col + 0.5) / grid, 1.0 - (row + 0.5) / grid])
            left, top = (MARGIN + col * cell) * s, (MARGIN + row * cell) * s
            draw.rectangle((left, top, left + cell * s - 1, top + cell * s - 1), fill=_cell_colour(z))
            distance = np.linalg.norm(palette.exemplar_z - z, axis=1)
            nearest = int(np.argmin(distance))
            if distance[nearest] > 0.75 / grid:
                continue
            points = palette.exemplar_points[nearest]
            inside = points[np.all(points < window, axis=1)] / window
            inset = 4 * s
            _draw_pattern(draw, inside, (left + inset, top + inset, cell * s - 2 * inset), radius)
    image = image.resize((size + 2 * MARGIN, size + 2 * MARGIN), Image.Resampling.LANCZOS)
    _annotate(ImageDraw.Draw(image), palette, grid, cell)
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG")


def draw_continuous_palette(palette: Palette, path: str | os.PathLike, size: int = 768, points: int = 20_000, seed: int = 0) -> None:
    """Write the continuous palette (paper Fig. 4): one synthesised pattern whose correlation
    varies over the ab plane (a left to right, b bottom to top) at constant density."""
    from synthesis.render import rasterize_dots
    from synthesis.synthesize import synthesize

    z = (np.arange(LUT_SIDE) + 0.5) / LUT_SIDE
    za, zb = np.meshgrid(z, 1.0 - z)
    lab = np.stack([np.full_like(za, 50.0), latent_to_ab(za), latent_to_ab(zb)], axis=-1)
    result = synthesize(LabMap(lab), n=points, palette=palette, seed=seed)
    coverage = rasterize_dots(result.points, size)
    image = Image.new("RGB", (size + 2 * MARGIN, size + 2 * MARGIN), (255, 255, 255))
    image.paste(Image.fromarray(np.rint(255 * (1 - coverage)).astype(np.uint8)).convert("RGB"), (MARGIN, MARGIN))
    _annotate(ImageDraw.Draw(image), palette, size, 1, title="Patternshop continuous palette: one pattern, correlation varying over (a, b)")
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG")


def _annotate(draw: ImageDraw.ImageDraw, palette: Palette, grid: int, cell: int,
              title: str = "Patternshop correlation palette (CIELAB a, b)") -> None:
    """Axes ticks and labels, title, and a ring with the name of every preset."""
    font = ImageFont.load_default(size=13)
    size = grid * cell
    draw.text((MARGIN, 14), title, fill=(0, 0, 0), font=font)
    for value in (-128, -64, 0, 64, 127):
        z = ab_to_latent(value)
        x = MARGIN + z * size
        y = MARGIN + (1.0 - z) * size
        draw.text((x, MARGIN + size + 6), f"{value}", fill=(0, 0, 0), font=font, anchor="mt")
        draw.text((MARGIN - 6, y), f"{value}", fill=(0, 0, 0), font=font, anchor="rm")
    draw.text((MARGIN + size / 2, MARGIN + size + 26), "a", fill=(0, 0, 0), font=font, anchor="mt")
    draw.text((16, MARGIN + size / 2), "b", fill=(0, 0, 0), font=font, anchor="mm")
    for name, (a, b) in palette.preset_ab().items():
        za, zb = ab_to_latent(np.array([a, b]))
        x, y = MARGIN + za * size, MARGIN + (1.0 - zb) * size
        draw.ellipse((x - 9, y - 9, x + 9, y + 9), outline=(255, 255, 255), width=4)
        draw.ellipse((x - 9, y - 9, x + 9, y + 9), outline=(0, 0, 0), width=2)
        box = draw.textbbox((x + 12, y), name, font=font, anchor="lm")
        draw.rectangle((box[0] - 2, box[1] - 1, box[2] + 2, box[3] + 1), fill=(255, 255, 255))
        draw.text((x + 12, y), name, fill=(0, 0, 0), font=font, anchor="lm")
