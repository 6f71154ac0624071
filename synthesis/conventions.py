"""Conventions shared by the library and the command line, importable without numpy (``patternshop --help`` stays fast)."""

POINTS_PER_INK = 50_000  # points per unit area of full ink (paper's training data, on unit squares); see POINTS_PER_INK_MEANING
POINTS_PER_INK_MEANING = (
    "points per unit area of full ink (L = 0); the map's longer side is 1, so a W x H px map has area "
    "min(W, H) / max(W, H) and gets points-per-ink x area x mean(1 - L/100) points: a dark region has the same "
    "dot density on any canvas shape")


def full_ink_points(points_per_ink: float, domain: tuple[float, float]) -> float:
    """Points a fully dark map of ``domain`` (w, h), longer side 1, holds at ``points_per_ink`` (per unit area): ``points_per_ink x w x h``."""
    return points_per_ink * domain[0] * domain[1]
