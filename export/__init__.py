"""ONNX export, ONNX Runtime inference and batch conversion.

Filled by the inference issue; importable now so the package layout (SPEC §4)
is in place.
"""
