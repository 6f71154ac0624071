"""Hydra configuration files (YAML only; this file makes the folder installable as package data).

In a checkout they are the top-level ``conf/`` folder; an installed wheel holds them as ``patternshop/conf``.
Code finds them with :data:`data_gen.provenance.CONF_DIR`, never by importing a ``conf`` module.
"""
