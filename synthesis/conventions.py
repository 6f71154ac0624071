"""Conventions shared by the library and the command line, importable without numpy (``patternshop --help`` stays fast)."""

POINTS_PER_INK = 50_000  # points of a fully dark map: n = POINTS_PER_INK * mean density (paper's training data)
