"""The ``jaxstyle`` command line: the whole pipeline from data to animation, one subcommand per step.

    jaxstyle demo [--data PATH]        # procedural styles (no download) or your data -> GIF, BVH, sweep
    jaxstyle data generate|fetch|prepare
    jaxstyle train-base --data PATH    # Mason et al. 2018 base PFNN with per-style CP adapters
    jaxstyle sweep                     # few-shot styles x dropout rates in one compiled sweep
    jaxstyle lpn --data PATH           # Mason et al. 2022 LPN-FiLM: train, test, fine-tune new styles
    jaxstyle synthesize                # characters along user paths: GIF, BVH, quality figures
    jaxstyle render FILE.bvh ...       # a GIF of any BVH files
    jaxstyle bench                     # fine-tuning sweep against a loop, network speed

Every step that trains or writes results works in a run folder (``--run``, default
``runs/jaxstyle``; the demo's is ``runs/demo``): ``base/``, ``sweep/``, ``synthesis/``, ``lpn/``,
``cache/``, with ``config.json`` (the settings of each command run there) and ``log.txt`` (what
each printed). Settings come from flags or from a TOML file (``--config FILE``; flags win), whose
keys are the flags' long names (``base-epochs = 10``), at top level or in a table named after the
command. Bad arguments and missing files end with a one-line error; ``--debug`` shows the
traceback instead.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tomllib
from pathlib import Path
from typing import Callable, Sequence

from jaxstyle.cli import bench, data, demo, lpn, render, sweep, synthesize, train_base
from jaxstyle.cli.common import CLIError, Formatter, Parser, Run, resolve_defaults

COMMANDS = (demo, data, train_base, sweep, lpn, synthesize, render, bench)
"""The command modules, in the order of ``jaxstyle --help``: each has ``NAME``, ``HELP``, ``DOC``,
``add_arguments(parser)`` and ``run(args, run)``; :mod:`jaxstyle.cli.data` has ``ACTIONS`` instead."""


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The parser and, per command name (``"data fetch"`` for nested ones), its sub-parser."""
    from jaxstyle import __version__

    parser = Parser(prog="jaxstyle", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"jaxstyle {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    subs = {}
    for command in COMMANDS:
        p = sub.add_parser(command.NAME, help=command.HELP, description=command.DOC, formatter_class=Formatter)
        subs[command.NAME] = p
        if command is data:
            p.set_defaults(handler=None)
            actions = p.add_subparsers(dest="data_command", metavar="ACTION", parser_class=Parser)
            for name, help_text, doc, add_arguments, handler in data.ACTIONS:
                a = actions.add_parser(name, help=help_text, description=doc, formatter_class=Formatter)
                a.set_defaults(handler=handler)
                add_arguments(a)
                subs[f"data {name}"] = a
        else:
            p.set_defaults(handler=command.run)
            command.add_arguments(p)
    return parser, subs


def _command_name(args) -> str:
    return args.command if args.command != "data" else f"data {args.data_command}"


def _apply_config(parser, subs, args, argv):
    """Re-parse with the TOML file's settings as defaults (explicit flags still win)."""
    name = _command_name(args)
    try:
        settings = tomllib.loads(Path(args.config).read_text())
    except FileNotFoundError:
        raise CLIError(f"--config {args.config}: no such file") from None
    except tomllib.TOMLDecodeError as e:
        raise CLIError(f"--config {args.config}: not valid TOML ({e})") from None
    table = settings.get(name, settings.get(name.replace(" ", "-"), {}))
    flat = {k: v for k, v in settings.items() if not isinstance(v, dict)}
    flat.update(table if isinstance(table, dict) else {})
    sub = subs[name]
    dests = {a.dest: a for a in sub._actions}
    values = {}
    for key, value in flat.items():
        dest = key.replace("-", "_")
        if dest not in dests or dest in ("help", "config"):
            known = sorted(d.replace("_", "-") for d in dests if d not in ("help", "config", "handler"))
            raise CLIError(f"--config {args.config}: unknown setting {key!r} for `jaxstyle {name}`; known: "
                           f"{', '.join(known)}")
        action = dests[dest]
        values[dest] = action.type(value) if action.type is not None and isinstance(value, str) else value
    sub.set_defaults(**values)
    return parser.parse_args(argv)


KNOWN_ERRORS: tuple[type[BaseException], ...] = (CLIError, FileNotFoundError, NotADirectoryError, PermissionError,
                                                 ValueError, KeyError)


NEEDS_BASE = ("sweep", "synthesize")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (0 done, 1 failed, 2 bad arguments)."""
    from jaxstyle.errors import JaxstyleError

    argv = list(sys.argv[1:] if argv is None else argv)
    parser, subs = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    if args.command == "data" and args.data_command is None:
        subs["data"].print_help()
        return 2
    name = _command_name(args)
    errors = KNOWN_ERRORS + (JaxstyleError,)
    with contextlib.suppress(ImportError):
        from jaxstyle.data.fetch import FetchError

        errors += (FetchError,)
    run = None
    try:
        if args.config is not None:
            args = _apply_config(parser, subs, args, argv)
        resolve_defaults(args)
        handler: Callable = args.handler
        if name in NEEDS_BASE and not (Path(args.run) / "base" / "base.json").is_file():
            raise CLIError(f"no base model in {Path(args.run) / 'base'}: train one first with "
                           "`jaxstyle train-base --data PATH --run RUN` (or run `jaxstyle demo`)")
        if "run" in vars(args):
            run = Run(args.run, name, vars(args), argv)
        handler(args, run)
    except errors as e:
        if args.debug:
            raise
        message = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"jaxstyle {name}: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"jaxstyle {name}: interrupted (re-run the same command to resume)", file=sys.stderr)
        return 130
    finally:
        if run is not None:
            run.close()
    return 0


def entry_point() -> None:
    """The console script."""
    sys.exit(main())
