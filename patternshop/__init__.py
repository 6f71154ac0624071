"""Patternshop: edit point patterns as CIELAB images. The ``patternshop`` command lives here."""

from synthesis.version import package_version

__version__ = package_version()
