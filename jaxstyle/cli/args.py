"""The commands' argument parsing: the parser with one-line errors, defaults read from the library
when needed, the argument groups several commands share, and the checks of their values."""

from __future__ import annotations

import argparse
import importlib
import math
from pathlib import Path
from typing import Sequence

from jaxstyle.cli.common import DEFAULT_RUN, CLIError, check_input_file


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (and a pointer to ``--help``) instead of the usage block."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Raw descriptions; defaults shown unless there is none or the help already says it."""

    def _get_help_string(self, action):
        if action.default in (None, False) or "default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


class LazyDefault:
    """A default read from a library constant (``module``'s ``name``) only when it is needed: when
    help is shown or the command runs (:func:`resolve_defaults`), so that building the parser
    imports no JAX."""

    def __init__(self, module: str, name: str):
        self.module, self.name = module, name

    def value(self):
        value = getattr(importlib.import_module(self.module), self.name)
        return list(value) if isinstance(value, tuple) else value

    def __str__(self) -> str:
        value = self.value()
        return " ".join(map(str, value)) if isinstance(value, list) else str(value)


def resolve_defaults(args: argparse.Namespace) -> None:
    """Replace every :class:`LazyDefault` left in ``args`` by its value."""
    for key, value in vars(args).items():
        if isinstance(value, LazyDefault):
            setattr(args, key, value.value())


SWEEP_RATES = LazyDefault("jaxstyle.train.defaults", "DEFAULT_RATES")
"""The few-shot sweep's dropout rates (the library's default)."""

LEARN_EPOCHS = LazyDefault("jaxstyle.train.defaults", "LEARN_EPOCHS")
"""Fine-tuning epochs of a style learned live (the library's default)."""

PHASE_FLOOR = LazyDefault("jaxstyle.train.defaults", "PHASE_FLOOR")
"""The 2022 runtime's floor on the local phases' advance (the library's default)."""

FOOT_SMOOTH = LazyDefault("jaxstyle.train.defaults", "FOOT_SMOOTH")
"""The 2022 runtime's weight of the feet's predicted positions (the library's default)."""

BODY_SMOOTH = LazyDefault("jaxstyle.train.defaults", "BODY_SMOOTH")
"""The 2022 runtime's weight of the other bones' predicted positions (the library's default)."""


def add_common(parser: argparse.ArgumentParser, run_default: Path | None = DEFAULT_RUN) -> None:
    if run_default is not None:
        parser.add_argument("--run", type=Path, default=run_default,
                            help="run folder: models, reports, config.json and log.txt")
    parser.add_argument("--config", type=Path, help="TOML file of settings (keys = long flag names); flags win")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors")


def add_distributed_args(p: argparse.ArgumentParser) -> None:
    """``--distributed`` and its coordinator, process count and id (``jaxstyle.train.shard.initialize``)."""
    p.add_argument("--distributed", action="store_true",
                   help="one of several processes (hosts, or GPUs of one host) running this same command: "
                        "jax.distributed joins them, the work is split over all their devices, process 0 writes "
                        "(docs/scale.md)")
    p.add_argument("--coordinator", metavar="HOST:PORT",
                   help="with --distributed: process 0's address (default: JAX_COORDINATOR_ADDRESS or the cluster's)")
    p.add_argument("--num-processes", type=int,
                   help="with --distributed: how many processes (default: JAX_NUM_PROCESSES or the cluster's)")
    p.add_argument("--process-id", type=int,
                   help="with --distributed: this process, 0 .. count - 1 (default: JAX_PROCESS_ID or the cluster's)")


def add_joint_map_arg(p: argparse.ArgumentParser) -> None:
    """``--joint-map FILE``, for every command that reads a style folder (see :func:`joint_map`)."""
    p.add_argument("--joint-map", type=Path, metavar="FILE",
                   help="TOML or JSON file of role = [left joint, right joint] (roles: hips, shoulders, ankles, toes, "
                        "hands; or left_ankle = NAME ...) for a skeleton whose joints are not found by name")


def joint_map(args):
    """The :class:`~jaxstyle.motion.skeleton.JointMap` of ``--joint-map`` (``None`` without one); a
    missing file or a bad entry is a :class:`CLIError` naming the flag, the file and the key."""
    path = getattr(args, "joint_map", None)
    if path is None:
        return None
    from jaxstyle.errors import MotionDataError
    from jaxstyle.motion.skeleton import read_joint_map

    path = Path(path)
    check_input_file(path, "--joint-map", what="joint map file")
    try:
        return read_joint_map(path)
    except MotionDataError as e:
        raise CLIError(f"--joint-map {e}") from None


def add_base_args(p: argparse.ArgumentParser, *, hidden: int, epochs: int, rank: int) -> None:
    p.add_argument("--styles", nargs="+", help="base (training) styles (default: all but the few-shot ones)")
    p.add_argument("--fewshot-styles", nargs="+",
                   help="styles held out for the few-shot sweep (default: the procedural data's Limping and Proud, "
                        "100STYLE's Aeroplane, Elated and Rushed when present, else the last style)")
    p.add_argument("--gaits", nargs="+", help="100STYLE gait codes to use (default: the locomotion gaits "
                                               "BR BW FR FW SR SW)")
    p.add_argument("--hidden", type=int, default=hidden, help="hidden units of the PFNN (paper: 512)")
    p.add_argument("--rank", type=int, default=rank, help="rank of the CP adapters (paper: 30)")
    p.add_argument("--base-epochs", type=int, default=epochs, help="base training epochs (paper: 25)")
    p.add_argument("--max-seconds", type=finite, help="use only the first seconds of each base clip")
    add_joint_map_arg(p)


def add_sweep_args(p: argparse.ArgumentParser, *, epochs: int) -> None:
    p.add_argument("--seconds", type=finite, default=10.0, help="length of each few-shot clip (paper: a few seconds)")
    p.add_argument("--rates", type=finite, nargs="+", default=SWEEP_RATES, help="dropout rates to sweep")
    p.add_argument("--sweep-epochs", type=int, default=epochs, help="fine-tuning epochs per (set, rate) (paper: 100)")
    p.add_argument("--adapter-dropout-only", action="store_true",
                   help="faster mode: dropout on the adapter path only (see jaxstyle.mason2018.fewshot.SweepConfig)")


def add_synth_args(p: argparse.ArgumentParser, *, paths: Sequence[str], seconds: float) -> None:
    from jaxstyle.control.paths import PATHS

    p.add_argument("--paths", nargs="+", default=list(paths), choices=list(PATHS), help="paths to walk")
    p.add_argument("--synth-seconds", type=finite, default=seconds, help="length of each synthesised path")
    p.add_argument("--speed", type=finite, help="speed of every character, m/s (default: each style's own)")
    p.add_argument("--no-foot-lock", dest="foot_lock", action="store_false",
                   help="write the network's feet as they are (by default they are locked while planted, in the BVH "
                        "files and the animations)")
    p.add_argument("--mp4", action="store_true", help="also write MP4s (needs ffmpeg)")
    p.add_argument("--every", type=int, default=2, help="draw every n-th frame in the animations")
    p.add_argument("--allow-failed", action="store_true",
                   help="drive few-shot sets whose closed-loop check failed at every rate (marked [FAILED CHECK] in "
                        "the tables); by default such a set is refused with one line")
    add_lpn_runtime_args(p)


def add_lpn_runtime_args(p: argparse.ArgumentParser) -> None:
    """The 2022 runtime's settings (``--phase-floor``, ``--foot-smooth``, ``--body-smooth``) of every command that
    drives a 2022 model (:class:`jaxstyle.mason2022.synthesis.Loaded`)."""
    p.add_argument("--phase-floor", type=non_negative, default=PHASE_FLOOR, metavar="F",
                   help="2022 models: each limb's local phase advances at least F times its style's capture rate "
                        "per frame (0: the paper's runtime, whose closed loop can stall)")
    add_joint_blend_args(p)


def add_joint_blend_args(p: argparse.ArgumentParser, *, paper: bool = False) -> None:
    """``--foot-smooth`` and ``--body-smooth``: the 2022 runtime's weights of the feet's and the
    other bones' predicted positions in the blend it carries
    (:meth:`jaxstyle.control.lpn_controller.StyleNetModel.create`), in [0, 1]. Default the
    library's :data:`FOOT_SMOOTH` and :data:`BODY_SMOOTH` (the commands; :func:`resolve_defaults`
    gives their values), or with ``paper`` ``None``: the paper's 0.5 on every joint (the
    experiments whose recorded figures were measured so)."""
    default = "default 0.5, the paper's runtime" if paper else "default %(default)s; 0.5 is the paper's runtime"
    p.add_argument("--foot-smooth", type=fraction, default=None if paper else FOOT_SMOOTH, metavar="S",
                   help="2022 models: the feet carry S of their predicted positions and 1 - S of their positions "
                        f"moved on by their predicted velocities ({default}; docs/mason2022.md 'Feet that slide')")
    p.add_argument("--body-smooth", type=fraction, default=None if paper else BODY_SMOOTH, metavar="S",
                   help="2022 models: every other bone carries S of its predicted position and 1 - S of its position "
                        f"moved on by its predicted velocity ({default}; docs/mason2022.md 'Why Drunk glides')")


def finite(text: str) -> float:
    """argparse ``type`` of every number flag: a finite number (``nan``, ``inf`` and ``1e999`` are
    refused with argparse's one line naming the flag)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def non_negative(text: str) -> float:
    """argparse ``type``: a finite number >= 0."""
    value = finite(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def fraction(text: str) -> float:
    """argparse ``type``: a number in [0, 1]."""
    value = finite(text)
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return value


def check_rates(rates, flag: str = "--rates") -> None:
    """Dropout rates must lie in [0, 1)."""
    if any(not 0 <= r < 1 for r in rates):
        raise CLIError(f"{flag} must be in [0, 1), got {' '.join(f'{r:g}' for r in rates)}")


MAX_SYNTH_SECONDS = 3600.0  # one path's length at most (216,000 frames at 60 fps)
MAX_SPEED = 10.0  # m/s: a sprinter's top speed; the networks were trained on walking and running


def check_synthesis(args) -> None:
    """``--synth-seconds`` and ``--speed`` within what synthesis can draw and the networks know."""
    seconds, speed = getattr(args, "synth_seconds", None), getattr(args, "speed", None)
    if seconds is not None and seconds > MAX_SYNTH_SECONDS:
        raise CLIError(f"--synth-seconds must be at most {MAX_SYNTH_SECONDS:g} (one path), got {seconds:g}")
    if speed is not None and speed > MAX_SPEED:
        raise CLIError(f"--speed must be at most {MAX_SPEED:g} m/s, got {speed:g}")


def check_positive(args, *names: str) -> None:
    for name in names:
        value = getattr(args, name, None)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise CLIError(f"--{name.replace('_', '-')} must be positive and finite, got {value:g}")
