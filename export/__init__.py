"""ONNX export, ONNX Runtime inference, batch conversion and scriptable map edits.

* :mod:`export.onnx` — generator checkpoint -> ONNX model with metadata (needs torch, Lightning);
* :mod:`export.runtime` — ONNX Runtime inference: point sets -> maps (no torch);
* :mod:`export.convert` — folders of point files -> maps, and maps -> point files;
* :mod:`export.edits` — pure edits of maps (region correlation, density gradient, canvas).
"""
