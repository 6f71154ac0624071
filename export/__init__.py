"""Runtime inference and batch conversion: no torch, no Lightning.

* :mod:`export.runtime` — ONNX Runtime inference: point sets -> maps;
* :mod:`export.evidence` — what the points alone say about density (ink per point, pixels without points);
* :mod:`export.density` — the density post-processing of ``infer`` (sharpen, denoise, ink calibration);
* :mod:`export.convert` — folders of point files -> maps, and maps -> point files.

The ONNX exporter lives with the network (:mod:`patternshop_nn.onnx_export`), map edits with the other map
operations (:mod:`synthesis.edits`); see ``docs/architecture.md`` for which package may import which.
"""
