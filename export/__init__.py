"""Runtime inference and batch conversion: no torch, no Lightning.

* :mod:`export.runtime` — ONNX Runtime inference: point sets -> maps;
* :mod:`export.evidence` — what the points alone say about density (the scale to read them at, the ink they hold);
* :mod:`export.infer_config` — :class:`~export.infer_config.InferConfig`, the constants of ``infer`` around the network;
* :mod:`export.uncertainty` — L smoothed within the uncertainty a model predicts (``l_scale``);
* :mod:`export.convert` — folders of point files -> maps, and maps -> point files.

The ONNX exporter lives with the network (:mod:`patternshop_nn.onnx_export`), map edits with the other map
operations (:mod:`synthesis.edits`); see ``docs/architecture.md`` for which package may import which.
"""
