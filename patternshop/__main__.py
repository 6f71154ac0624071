"""``python -m patternshop`` is the ``patternshop`` command."""

from patternshop.cli import entry_point

entry_point()
