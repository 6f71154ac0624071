"""Step-size rule vs the paper's per-exemplar best learning rate (supplemental §1.2).

For a sample of palette exemplars, synthesise a constant map at n = 1024 with
Adam at each of the paper's seven fixed learning rates (domain units, 1,000
iterations, every point a centre) and keep the best per exemplar — the
paper's table entry — then compare with our rule (steps in units of the local
spacing, cosine decay) at 1,000 and at its default 250 iterations. Errors:
perceptual (L1 distance of Gram features to the exemplar's, as the paper's
criterion) and PCF (mean |PCF - target|). Results: ``out/bench/step_rule.json``.
"""

from __future__ import annotations

import numpy as np
import torch

from common import save_results  # bench/ is on sys.path when run as a script

from synthesis.features import FeatureExtractor, scale_blocks
from synthesis.labmap import LabMap
from synthesis.palette import load_palette
from synthesis.pcf import r_max, stationary_pcf
from synthesis.synthesize import SCHEDULES, Schedule, synthesize

PAPER_RATES = (0.02, 0.01, 0.005, 0.001, 0.0005, 0.0001, 0.00005)
EXEMPLARS = 8
N = 1024


def main() -> None:
    torch.set_num_threads(2)
    palette = load_palette()
    extractor = FeatureExtractor(palette.extractor["name"], palette.extractor.get("seed", 0))
    spacing = r_max(N)

    def errors(points: np.ndarray, index: int, target: np.ndarray) -> tuple[float, float]:
        own = scale_blocks(extractor(palette.exemplar_points[index], periodic=True), palette.block_scale)
        mine = scale_blocks(extractor(points, periodic=False), palette.block_scale)
        return float(np.abs(own - mine).sum()), float(np.abs(stationary_pcf(points, periodic=False) - target).mean())

    rows = []
    for index in np.linspace(0, len(palette.exemplar_z) - 1, EXEMPLARS).astype(int):
        a, b = 255.0 * palette.exemplar_z[index] - 128.0
        lab_map = LabMap(np.broadcast_to(np.array([50.0, a, b], np.float32), (64, 64, 3)))
        target = palette.pcf(a, b)
        fixed = {}
        for rate in PAPER_RATES:
            plan = Schedule(f"fixed-{rate}", 1000, True, 10, rate / spacing, rate / spacing)
            fixed[rate] = errors(synthesize(lab_map, n=N, palette=palette, schedule=plan, seed=1).points.xy, index, target)
        best = min(fixed, key=lambda r: fixed[r][0])
        ours_1000 = errors(synthesize(lab_map, n=N, palette=palette, iterations=1000, seed=1).points.xy, index, target)
        ours_250 = errors(synthesize(lab_map, n=N, palette=palette, seed=1).points.xy, index, target)
        rows.append({"exemplar": int(index), "best_paper_rate": best, "paper_best": fixed[best], "ours_1000": ours_1000,
                     "ours_250": ours_250})
        print(rows[-1], flush=True)
    summary = {name: [round(float(np.median([r[name][k] for r in rows])), 4) for k in (0, 1)]
               for name in ("paper_best", "ours_1000", "ours_250")}
    save_results("step_rule", {"rows": rows, "median_perceptual_and_pcf_error": summary,
                               "fast_schedule": SCHEDULES["fast"].__dict__, "n": N})


if __name__ == "__main__":
    main()
