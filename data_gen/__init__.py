"""Data generation: the correlation-palette corpus and the network's training pairs.

Filled by the palette and training-data issues; importable now so the package
layout (SPEC §4) is in place.
"""
