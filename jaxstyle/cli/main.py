"""The ``jaxstyle`` command line: the whole pipeline from data to animation, one subcommand per step.

    jaxstyle demo [--data PATH]        # procedural styles (no download) or your data -> GIF, BVH, sweep
    jaxstyle data generate|fetch|prepare
    jaxstyle train-base --data PATH    # Mason et al. 2018 base PFNN with per-style CP adapters
    jaxstyle sweep                     # few-shot styles x dropout rates in one compiled sweep
    jaxstyle lpn --data PATH           # Mason et al. 2022 LPN-FiLM: train, test, fine-tune new styles
    jaxstyle synthesize                # characters along user paths: GIF, BVH, quality figures
    jaxstyle render FILE.bvh ...       # a GIF of any BVH files
    jaxstyle bench                     # fine-tuning sweep against a loop, network speed
    jaxstyle play [--run RUN]          # steer a styled character live in the browser

Every step that trains or writes results works in a run folder (``--run``, default
``runs/jaxstyle``; the demo's is ``runs/demo``): ``base/``, ``sweep/``, ``synthesis/``, ``lpn/``,
``cache/``, with ``config.json`` (the settings of each command run there) and ``log.txt`` (what
each printed). Settings come from flags or from a TOML file (``--config FILE``; flags win), whose
keys are the flags' long names (``base-epochs = 10``), at top level or in a table named after the
command; each value is checked against its flag (type, number of values, choices). Bad arguments,
settings and files, and unforeseen failures, end with ONE line on stderr naming the flag, setting
or path at fault (exit status 1, or 2 for argparse's own errors); ``--debug`` shows the traceback
instead.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tomllib
from pathlib import Path
from typing import Callable, Sequence

from jaxstyle.cli import bench, data, demo, lpn, play, render, sweep, synthesize, train_base
from jaxstyle.cli.args import Formatter, Parser, finite, resolve_defaults
from jaxstyle.cli.common import (
    CLIError,
    Run,
    check_input_file,
    check_input_folder,
    describe_os_error,
    ensure_folder,
    file_in_the_way,
    one_line,
    start_distributed,
    use_xla_cache,
)

COMMANDS = (demo, data, train_base, sweep, lpn, synthesize, render, bench, play)
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


def _read_config(path: Path) -> dict:
    """The settings of a TOML file, or a one-line :class:`CLIError` naming it."""
    if path.is_dir():
        raise CLIError(f"--config {path}: is a folder, not a TOML file")
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        blocker = file_in_the_way(path)
        raise CLIError(f"--config {path}: no such file" + (f" ({blocker} is a file, not a folder)" if blocker
                                                           else "")) from None
    except OSError as e:
        raise CLIError(f"--config {path}: cannot read it: {describe_os_error(e)}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = None
    if text is None or "\x00" in text:
        raise CLIError(f"--config {path}: not a text file (expected a TOML file of settings)")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise CLIError(f"--config {path}: not valid TOML ({one_line(e)})") from None


def _toml(value) -> str:
    """``value`` as it would be written in TOML (for messages)."""
    try:
        return json.dumps(value)
    except (TypeError, ValueError):
        return str(value)


_KINDS = {int: ("an integer", "integers"), float: ("a number", "numbers"), finite: ("a number", "numbers"),
          Path: ("a path", "paths"), None: ("a string", "strings")}


def _convert_one(action: argparse.Action, value, where: str):
    """One value of a setting converted as argparse converts the flag's words, or a CLIError."""
    kind = _KINDS.get(action.type, ("a valid value", "valid values"))[0]
    bad = CLIError(f"{where}: expected {kind}, got {_toml(value)}")
    if isinstance(value, (bool, dict, list)):
        raise bad
    if action.type is int and not isinstance(value, (int, str)):
        raise bad
    if action.type in (float, finite) and not isinstance(value, (int, float, str)):
        raise bad
    if (action.type in (None, Path) and not isinstance(value, str)) or value == "":
        raise bad
    try:
        converted = value if action.type is None else action.type(value)
    except (TypeError, ValueError, argparse.ArgumentTypeError):
        raise bad from None
    if action.choices is not None and converted not in action.choices:
        raise CLIError(f"{where}: invalid choice {_toml(value)} (choose from {', '.join(map(str, action.choices))})")
    return converted


def config_value(action: argparse.Action, value, where: str):
    """A setting of a ``--config`` file checked against its flag's argparse ``action`` (type,
    number of values, choices) and converted; ``where`` (``FILE: key``) starts the one-line
    :class:`CLIError` otherwise. A single value is taken as a one-item list where the flag takes
    several (``styles = "Neutral"``)."""
    if isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction)):
        if not isinstance(value, bool):
            raise CLIError(f"{where}: expected true or false, got {_toml(value)}")
        return value
    nargs = action.nargs
    if nargs in (None, "?"):
        return _convert_one(action, value, where)
    kind = _KINDS.get(action.type, ("a valid value", "valid values"))
    if not isinstance(value, list):
        if isinstance(nargs, int) and nargs != 1:
            raise CLIError(f"{where}: expected a list of {nargs} {kind[1]}, got {_toml(value)}")
        value = [value]
    if isinstance(nargs, int) and len(value) != nargs:
        raise CLIError(f"{where}: expected a list of {nargs} {kind[1]}, got {_toml(value)}")
    if nargs == "+" and not value:
        raise CLIError(f"{where}: expected at least one value ({kind[0]} or a list of {kind[1]}), got []")
    return [_convert_one(action, v, f"{where}[{i}]" if len(value) > 1 else where) for i, v in enumerate(value)]


_NOT_SETTINGS = ("help", "config", "version")


def _apply_config(parser, subs, args, argv):
    """Re-parse with the TOML file's settings as defaults (explicit flags still win)."""
    name = _command_name(args)
    path = Path(args.config)
    settings = _read_config(path)
    table_name, table = name, None
    for key in (name, name.replace(" ", "-")):
        if isinstance(settings.get(key), dict):
            table_name, table = key, settings[key]
            break
    if table is None and " " in name and isinstance(settings.get(name.split()[0]), dict):
        outer, inner = name.split()  # [data.generate]
        if isinstance(settings[outer].get(inner), dict):
            table_name, table = f"{outer}.{inner}", settings[outer][inner]
    flat = {k: (k, v) for k, v in settings.items() if not isinstance(v, dict)}
    flat.update({k: (f"{table_name}.{k}", v) for k, v in (table or {}).items()})
    sub = subs[name]
    dests = {a.dest: a for a in sub._actions}
    values = {}
    for key, (where, value) in flat.items():
        dest = key.replace("-", "_")
        if dest not in dests or dest in _NOT_SETTINGS:
            known = sorted(d.replace("_", "-") for d in dests if d not in _NOT_SETTINGS + ("handler",))
            raise CLIError(f"--config {path}: unknown setting {key!r} for `jaxstyle {name}`; known: "
                           f"{', '.join(known)}")
        values[dest] = config_value(dests[dest], value, f"{path}: {where}")
    sub.set_defaults(**values)
    return parser.parse_args(argv)


def _check_paths(args) -> None:
    """The input files and folders named on the command line, checked before anything runs."""
    if getattr(args, "data", None) is not None:
        check_input_folder(Path(args.data), "--data")
    if getattr(args, "run", None) is not None:
        check_input_folder(Path(args.run), "--run")  # (created, and checked writable, later)
    if getattr(args, "dest", None) is not None:
        check_input_folder(Path(args.dest), "--dest")  # data fetch (creates it)
    for f in getattr(args, "files", None) or ():  # render's BVH files
        check_input_file(Path(f), what="BVH file")
    for f in getattr(args, "clip", None) or ():
        check_input_file(Path(f), "--clip", what="BVH file")
    if getattr(args, "mp4", False):
        from matplotlib import animation

        if not animation.writers.is_available("ffmpeg"):
            raise CLIError("--mp4: writing MP4 needs ffmpeg, which was not found; leave --mp4 out for GIFs only")


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
        _check_paths(args)
        if (name in NEEDS_BASE and getattr(args, "model", "pfnn") == "pfnn"  # the 2022 models load their own
                and not (Path(args.run) / "base" / "base.json").is_file()):
            raise CLIError(f"no base model in {Path(args.run) / 'base'}: train one first with "
                           "`jaxstyle train-base --data PATH --run RUN` (or run `jaxstyle demo`)")
        use_xla_cache()
        writer = start_distributed(args)
        if "run" in vars(args):
            if writer:
                ensure_folder(Path(args.run), "--run")
            try:
                # play writes only RUN/play (its own learned styles and recordings): it runs beside the others
                run = Run(args.run, name, vars(args), argv, writer=writer, lock=name != "play")
            except OSError as e:
                raise CLIError(f"--run {args.run}: {describe_os_error(e)}") from None
        handler(args, run)
        if getattr(args, "distributed", False):
            from jaxstyle.train import shard

            shard.finish()
    except OSError as e:  # a file or folder the command could not read or write
        if args.debug:
            raise
        print(f"jaxstyle {name}: error: {describe_os_error(e)}", file=sys.stderr)
        return 1
    except errors as e:
        if args.debug:
            raise
        message = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"jaxstyle {name}: error: {one_line(message) or type(e).__name__}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"jaxstyle {name}: interrupted (re-run the same command to resume)", file=sys.stderr)
        return 130
    except Exception as e:  # a bug, or a failure nothing above foresaw: still one line
        if args.debug:
            raise
        print(f"jaxstyle {name}: internal error: {type(e).__name__}: {one_line(e)} (run with --debug for the "
              "traceback)", file=sys.stderr)
        return 1
    finally:
        if run is not None:
            run.close()
    return 0


def entry_point() -> None:
    """The console script."""
    sys.exit(main())
