"""The ``jaxstyle`` command line, one module per command; :mod:`jaxstyle.cli.main` assembles them.

* :mod:`~jaxstyle.cli.main`: the parser, ``--config`` TOML files, one-line errors (``--debug``: the
  traceback), :func:`main` and the console script's :func:`entry_point`;
* :mod:`~jaxstyle.cli.common`: the run folder (:class:`Run`), one-line path errors, helpers;
* :mod:`~jaxstyle.cli.args`: the parser with one-line errors, shared argument groups, value checks;
* one module per command, each argument parsing and a thin call into a pipeline
  (:mod:`jaxstyle.mason2018.pipeline`, :mod:`jaxstyle.mason2022.pipeline`): :mod:`~jaxstyle.cli.demo`,
  :mod:`~jaxstyle.cli.data` (generate, fetch, prepare), :mod:`~jaxstyle.cli.train_base`,
  :mod:`~jaxstyle.cli.sweep`, :mod:`~jaxstyle.cli.lpn`, :mod:`~jaxstyle.cli.synthesize`,
  :mod:`~jaxstyle.cli.render`, :mod:`~jaxstyle.cli.bench`.

``jaxstyle --help`` (or ``python -m jaxstyle.cli --help``) lists the commands.
"""

from jaxstyle.cli.common import DATA_HELP, DEFAULT_RUN, DEMO_RUN, CLIError, Run
from jaxstyle.cli.demo import DEMO_MAX_BASE_STYLES, demo_base_styles
from jaxstyle.cli.main import KNOWN_ERRORS, NEEDS_BASE, build_parser, entry_point, main

__all__ = ["CLIError", "DATA_HELP", "DEFAULT_RUN", "DEMO_MAX_BASE_STYLES", "DEMO_RUN", "KNOWN_ERRORS", "NEEDS_BASE",
           "Run", "build_parser", "demo_base_styles", "entry_point", "main"]
