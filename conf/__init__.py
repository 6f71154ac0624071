"""Hydra configuration files.

This folder is installed as the package ``conf`` so that Hydra finds it both in
a source checkout (``config_path="../conf"``) and in an installed copy
(``pkg://conf``).
"""
