"""Presets the palette can tell apart: each pair at least 15 ab units apart, merged names still accepted."""

from __future__ import annotations

import numpy as np
import pytest

from synthesis.errors import PatternshopError, PatternshopWarning
from synthesis.palette import MERGED_PRESETS, load_palette

def test_presets_are_perceptually_distinct_and_merged_names_still_work() -> None:
    palette = load_palette()
    presets = palette.preset_ab()
    names = list(presets)
    distances = [np.hypot(presets[p][0] - presets[q][0], presets[p][1] - presets[q][1])
                 for i, p in enumerate(names) for q in names[i + 1 :]]
    assert min(distances) >= 15.0  # measured: 18 (blue-step)
    assert not set(MERGED_PRESETS) & set(names)
    for old, new in MERGED_PRESETS.items():
        with pytest.warns(PatternshopWarning, match=f"'{old}' is merged into '{new}'"):
            assert palette.preset(old) == presets[new]
    with pytest.raises(PatternshopError, match="unknown preset 'nope'"):
        palette.preset("nope")
