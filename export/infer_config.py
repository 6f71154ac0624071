"""What ``infer`` does around the network, in one place: :class:`InferConfig`.

``infer``, ``convert``, :mod:`patternshop.api` and the studio read :data:`DEFAULT_INFER`; pass another
:class:`InferConfig` to :func:`export.runtime.infer_map` to try a change. Each field's docstring line names
the measurement that set it. A model without an ``l_scale`` output reads the same way with the smoothing
left out (no uncertainty to smooth within).
"""

from __future__ import annotations

from dataclasses import dataclass

SYMMETRY_CHOICES = (1, 2, 4, 8)  # readings averaged over this many symmetries of the square (codes 0 .. n-1 of export.runtime.dihedral)


@dataclass(frozen=True)
class InferConfig:
    """The constants of ``infer`` around the network (see the module docstring).

    Attributes:
        scale_cell_points: the scale of a pattern without one (:func:`export.evidence.choose_points_per_ink`) comes
            from a density grid whose cells hold this many points at full ink at the default scale ...
        scale_sigma_cells: ... blurred by a Gaussian of this many cells: about 800 points under the kernel at full ink,
            3.5 % noise for a Poisson pattern.
        scale_quantile: the quantile of that local density that is to read as full ink (the densest 1 % may read
            denser) ...
        scale_threshold: ... once it exceeds this (else the default scale): above the quantile of full-ink Poisson
            patterns, 1.07-1.09 (``tests/test_infer_evidence.py::test_scale_is_raised_only_for_patterns_denser_than_full_ink``).
        border_px: raster pixels of the pattern mirrored beyond each side of the domain. Without it v2 darkened a
            rim along the border (it learnt the synthesiser's thinner borders, commit e1baa63); 32 is half the
            U-Net's 64-px cell, not tuned further.
        symmetries: readings averaged per map by ``infer`` (one network pass each; a model without ``l_scale``
            too). The most that fit 1 s per 20,000-point map on one thread (``bench/bench_infer.py``, v6b: ``infer_map``
            0.28-0.29 s at 2, load 1-2; 0.58-0.76 s at 2 and 1.04-1.41 s at 4, load 2-5; the command takes about 0.9 s
            more to start); on the 12 development stipplings 2 give most of what
            4 give (interim v6b epoch 0, k 0.5: mean SSIM 0.597, 0.599, 0.600 at 1, 2, 4; MAE 5.56, 5.53, 5.52).
        convert_symmetries: the same for ``convert``, whose target is 10 files/s on two workers: one pass per file.
        smoothing_tolerance: k of :func:`export.uncertainty.smooth_by_uncertainty`: a pixel takes a Gaussian
            smoothing while the change it makes stays within k times the predicted Laplace scale of its density.
            Chosen for v15 (re-measured for v18, its path distilled: the same figures; v19 keeps v18's L) on the 12 development stipplings (``bench/bench_uncertainty.py
            --tolerances 0.15,0.25,0.35,0.5 --cases``: the four development pictures of ``patternshop_nn.ood`` by
            its three stipplers, seed 1000; 2 symmetries): mean SSIM 0.628 unsmoothed, 0.647, 0.651, 0.648, 0.640 at
            k 0.15, 0.25, 0.35, 0.5; MAE 4.66, 4.59, 4.59, 4.64, 4.78; better than the oracle KDE in SSIM and MAE in
            8, 9, 10, 9, 8 of 12: 0.25, the best SSIM and MAE. The best k moves with training (v6b 0.35, v9b 0.25,
            v9 0.35, v10 0.25, v11 0.25, v12 0.25, v14 0.25; docs/network.md): re-measure it for each model.
        smoothing_start_px: the first smoothing level's Gaussian (map px); each next level doubles it. On 256-px
            maps a 1-16 px KDE is the best one for the evaluation's stipplings (``patternshop_nn.ood``, oracle
            bandwidths), so the ladder spans them.
        smoothing_max_fraction: the widest level, as a fraction of the map's long side (16 px on 256 px, as above).
        smoothing_window: a level's change is measured in Gaussian windows this many times its width ...
        smoothing_min_window_px: ... and never narrower: a narrower window's average is too noisy an estimate and
            leaves specks unsmoothed (both chosen for v5's denoising on the four development pictures, of 2-4 and
            3-12 px, docs/history/model-v5.md).
        smoothing_window_truncate: the windows of :func:`export.uncertainty.smooth_by_uncertainty` are Gaussians cut at
            this many sigmas: as averages they need no tails, and at 2 instead of scipy's 4 the smoothing took 81 ms
            instead of 134 ms per 256-px map (cProfile of ``convert_points`` on 18 files, load 5-6).
        smoothing_softness: a level fades in over +- this share of its threshold, so neighbouring pixels that take
            different levels meet without a seam (v5's denoising, docs/history/model-v5.md; not tuned).
    """

    scale_cell_points: float = 16.0
    scale_sigma_cells: float = 2.0
    scale_quantile: float = 0.99
    scale_threshold: float = 1.15
    border_px: int = 32
    symmetries: int = 2
    convert_symmetries: int = 1
    smoothing_tolerance: float = 0.25
    smoothing_start_px: float = 1.0
    smoothing_max_fraction: float = 1.0 / 16
    smoothing_window: float = 2.0
    smoothing_min_window_px: float = 8.0
    smoothing_window_truncate: float = 2.0
    smoothing_softness: float = 0.25

    def __post_init__(self) -> None:
        for name in ("symmetries", "convert_symmetries"):
            if getattr(self, name) not in SYMMETRY_CHOICES:
                raise ValueError(f"{name} must be one of {SYMMETRY_CHOICES}, got {getattr(self, name)}")
        if self.border_px < 0 or self.smoothing_tolerance < 0 or self.smoothing_start_px <= 0 or self.smoothing_softness <= 0:
            raise ValueError(f"border, tolerance >= 0 and smoothing widths, softness > 0 needed: {self}")


DEFAULT_INFER = InferConfig()
