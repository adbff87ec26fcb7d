"""``python -m jaxstyle.cli``: the same entry point as the ``jaxstyle`` console script."""

from jaxstyle.cli import entry_point

entry_point()
