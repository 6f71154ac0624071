"""bench/bench_inference_targets.py: issue 28's development targets, judged from measured figures."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))

import bench_inference_targets as bench  # noqa: E402


def results(ssim: float, distance: float, spread: float, p95: float, empty_L: float) -> dict:
    """Measured figures of the four sections, one case each."""
    return {"textured": [{"ssim_at_least_oracle": ssim >= 0.5}],
            "stationary": {"sobol": {"distance": distance, "rotation_spread": spread,
                                     "colour_met": distance <= bench.COLOUR_TARGET, "spread_met": spread <= bench.SPREAD_TARGET}},
            "poisson_white": [{"picture": "camera", "light_chroma_p95": p95, "edges_chroma_p95": 1.0, "met": p95 <= bench.WHITE_CHROMA}],
            "nothing_invented": {"empty_min_L": empty_L, "one_point_share_L95": 1.0, "L_locked_64": 0.01,
                                 "ab_locked_64": 0.01, "met": empty_L >= 97}}


def test_each_target_is_missed_when_its_figure_is_past_it() -> None:
    assert all(row["met"] for row in bench.targets(results(0.6, 5.0, 2.0, 3.0, 100.0)))
    for bad, missed in ((results(0.4, 5.0, 2.0, 3.0, 100.0), 0), (results(0.6, 12.0, 2.0, 3.0, 100.0), 1),
                        (results(0.6, 5.0, 9.0, 3.0, 100.0), 1), (results(0.6, 5.0, 2.0, 20.0, 100.0), 2),
                        (results(0.6, 5.0, 2.0, 3.0, 90.0), 3)):
        assert [row["met"] for row in bench.targets(bad)] == [k != missed for k in range(4)]


def test_textured_pictures_are_the_protocols() -> None:
    """coins, astronaut, then the textures items: densities in [0, 1], the textures square, the same on a second call."""
    first, second = bench.textured_pictures(2), bench.textured_pictures(2)
    assert [name for name, _, _ in first] == ["coins", "astronaut", "textures 0", "textures 1"]
    for (_, density, domain), (_, again, _) in zip(first, second, strict=True):
        assert density.min() >= 0 and density.max() <= 1 and np.array_equal(density, again)
    assert first[2][2] == (1.0, 1.0) and first[2][1].shape == (256, 256)
