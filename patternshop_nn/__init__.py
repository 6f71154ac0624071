"""The points-to-map network: model, Lightning modules, training and inference.

Filled by the network issue; importable now so the package layout (SPEC §4) is
in place.
"""
