"""What every command shares: the run folder, argument groups, one-line errors, small helpers."""

from __future__ import annotations

import argparse
import contextlib
import datetime
import importlib
import math
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Sequence

DEFAULT_RUN = Path("runs/jaxstyle")
DEMO_RUN = Path("runs/demo")
DATA_HELP = ("a style folder: <Style>/<Style>_<GAIT>.bvh files, with 100STYLE's Frame_Cuts.csv or without it (whole "
             "files), or a folder holding 100style/")


class CLIError(Exception):
    """A problem with the user's arguments or files, reported on one line."""


# --- paths: one-line descriptions of what is wrong with them -----------------------------------

def one_line(message) -> str:
    """``message`` on one line (its non-empty lines joined by spaces)."""
    return " ".join(line.strip() for line in str(message).splitlines() if line.strip())


def file_in_the_way(path: str | os.PathLike) -> Path | None:
    """The nearest ancestor of ``path`` that exists as something other than a folder (a regular
    file), if any: the reason a folder cannot be created there."""
    for parent in Path(path).parents:
        if parent.exists():
            return None if parent.is_dir() else parent
    return None


def describe_os_error(e: OSError) -> str:
    """One line for an :class:`OSError`: the path(s) it names and the problem, e.g.
    ``runs/x/sub: not a directory (runs/x is a file)``."""
    problem = e.strerror or one_line(e) or type(e).__name__
    problem = problem[:1].lower() + problem[1:]
    if e.filename is None:
        return f"{type(e).__name__}: {problem}"
    where = os.fsdecode(e.filename) if isinstance(e.filename, (str, bytes, os.PathLike)) else str(e.filename)
    if e.filename2 is not None:
        where += f" -> {os.fsdecode(e.filename2)}"
    if isinstance(e, (NotADirectoryError, FileNotFoundError)):
        blocker = file_in_the_way(where.split(" -> ")[0])
        if blocker is not None:
            problem += f" ({blocker} is a file, not a folder)"
    return f"{where}: {problem}"


def ensure_folder(folder: Path, flag: str, target: Path | None = None) -> Path:
    """Create ``folder`` (parents too) and check that files can be written in it, else raise a
    :class:`CLIError` naming ``flag`` and the path: the folder itself (``--run R``) or the file
    ``target`` to be written in it (``--out R/x.gif``)."""
    folder = Path(folder)
    subject = f"{flag} {folder if target is None else target}"
    it = "" if target is None else f" {folder}"
    if folder.exists() and not folder.is_dir():
        raise CLIError(f"{subject}: {'' if target is None else f'{folder} '}is a file, not a folder")
    blocker = file_in_the_way(folder)
    if blocker is not None:
        raise CLIError(f"{subject}: cannot create the folder{it}: {blocker} is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise CLIError(f"{subject}: cannot create the folder{it}: {describe_os_error(e)}") from None
    try:
        tempfile.TemporaryFile(dir=folder).close()
    except OSError as e:
        raise CLIError(f"{subject}: cannot write in the folder{it}: {(e.strerror or str(e)).lower()}") from None
    return folder


def check_input_file(path: Path, flag: str = "", what: str = "file") -> None:
    """Raise a :class:`CLIError` unless ``path`` is an existing file (not a folder)."""
    subject = f"{flag} {path}" if flag else str(path)
    if path.is_dir():
        raise CLIError(f"{subject}: is a folder, not a {what}")
    if not path.exists():
        blocker = file_in_the_way(path)
        raise CLIError(f"{subject}: no such file" + (f" ({blocker} is a file, not a folder)" if blocker else ""))
    if not path.is_file():
        raise CLIError(f"{subject}: not a regular file")


def check_input_folder(path: Path, flag: str) -> None:
    """Raise a :class:`CLIError` when ``path`` exists but is not a folder, or cannot exist because a
    file stands where one of its parents should be (a plainly missing folder is left to the
    command, whose message says what such a folder must hold or creates it)."""
    if path.exists() and not path.is_dir():
        raise CLIError(f"{flag} {path}: is a file, not a folder")
    blocker = file_in_the_way(path)
    if blocker is not None:
        raise CLIError(f"{flag} {path}: {blocker} is a file, not a folder")


# --- the run folder -----------------------------------------------------------------------------

def _jsonable(value):
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    return value


_UNSAVED = ("handler", "debug", "quiet")


class Run:
    """A run folder: ``say`` prints and appends to ``log.txt``; the command's settings are saved in
    ``config.json`` under the command's name (earlier commands' entries are kept). ``writer=False``
    (a process other than 0 of a ``--distributed`` run) writes and prints nothing."""

    def __init__(self, directory: Path, command: str, settings: dict, argv: Sequence[str], *, writer: bool = True,
                 lock: bool = True):
        self.dir = Path(directory)
        self.command = command
        self.writer = writer
        self._lock = self._log = None
        if not writer:  # another process of a --distributed run: process 0 writes and reports
            return
        self.dir.mkdir(parents=True, exist_ok=True)
        if lock:
            self._lock = lock_run(self.dir, argv)
        try:
            self.save_settings(settings)
            self._log = open(self.dir / "log.txt", "a", encoding="utf-8")
        except BaseException:
            self.close()  # the lock too
            raise
        stamp = datetime.datetime.now().isoformat(timespec="seconds")
        self._log.write(f"\n=== {stamp} jaxstyle {' '.join(argv)}\n")
        self._log.flush()

    def save_settings(self, settings: dict) -> None:
        """Write ``settings`` into ``config.json`` under this command's name (atomically)."""
        config_path = self.dir / "config.json"
        config = {}
        if config_path.is_file():
            from jaxstyle.train.checkpoint import read_json  # loads JAX, so here

            try:
                config = read_json(config_path)
            except ValueError as e:
                raise CLIError(f"{e}; it holds the settings of the commands run here: fix it by hand") from None
            if not isinstance(config, dict):
                raise CLIError(f"{config_path}: expected a JSON object of the commands' settings, got "
                               f"{type(config).__name__}; fix it by hand")
        config[self.command] = _jsonable({k: v for k, v in settings.items() if k not in _UNSAVED})
        tmp = config_path.with_name("config.json.tmp")
        from jaxstyle.train.checkpoint import json_text  # strict JSON (NaN -> null); loads JAX, so here

        tmp.write_text(json_text(config))
        os.replace(tmp, config_path)

    def say(self, text: str = "") -> None:
        if self._log is None:
            return
        print(text, flush=True)
        self._log.write(text + "\n")
        self._log.flush()

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None
        if self._lock is not None:
            self._lock.close()  # releases the lock
            self._lock = None


LOCK_FILE = ".jaxstyle.lock"


def lock_run(directory: Path, argv: Sequence[str]):
    """Take the run folder's advisory lock (``flock`` on ``RUN/.jaxstyle.lock``, which names the
    holder) or raise a CLIError naming the command that holds it. The operating system releases
    the lock when its process ends, however it ends, so a killed command leaves no stale lock.
    Returns the open lock file (closing it releases the lock)."""
    import fcntl

    path = Path(directory) / LOCK_FILE
    f = open(path, "a+", encoding="utf-8")
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.seek(0)
        holder = f.read().strip() or "another process"
        f.close()
        raise CLIError(f"--run {directory}: in use by {holder}; wait until it finishes (one command writes a run "
                       "folder at a time)") from None
    f.seek(0)
    f.truncate()
    f.write(f"pid {os.getpid()} (jaxstyle {' '.join(argv)})"[:300])
    f.flush()
    return f


# --- argument parsing ---------------------------------------------------------------------------

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


XLA_CACHE_VAR = "JAXSTYLE_XLA_CACHE"


def xla_cache_dir() -> Path | None:
    """Where the command line keeps compiled programs between runs: ``$JAXSTYLE_XLA_CACHE``, else
    ``$XDG_CACHE_HOME/jaxstyle/xla`` (``~/.cache/jaxstyle/xla``); ``None`` when the variable is
    ``off`` (or empty)."""
    value = os.environ.get(XLA_CACHE_VAR)
    if value is not None:
        return None if value.strip().lower() in ("", "off", "0", "no") else Path(value).expanduser()
    home = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(home) / "jaxstyle" / "xla"


def use_xla_cache() -> Path | None:
    """Turn on JAX's persistent compilation cache in :func:`xla_cache_dir` (every program, however
    quick to compile), so a second ``jaxstyle play`` or ``jaxstyle sweep`` on the same base loads its
    programs instead of compiling them: a 10 s clip learned live is playable 8.7 s after its upload
    instead of 17.3 s on the demo's base (``python benchmarks/play.py --learn``, 2 CPU cores). A folder that
    cannot be made leaves the cache off. Returns the folder in use."""
    import jax

    folder = xla_cache_dir()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder


def start_distributed(args) -> bool:
    """Join the other processes when ``--distributed`` is given (before anything uses a device);
    returns whether this process writes the run folder (process 0, or the only process)."""
    if not getattr(args, "distributed", False):
        for flag in ("coordinator", "num_processes", "process_id"):
            if getattr(args, flag, None) is not None:
                raise CLIError(f"--{flag.replace('_', '-')} needs --distributed")
        return True
    from jaxstyle.train import shard

    shard.initialize(args.coordinator, args.num_processes, args.process_id)
    return shard.is_writer()


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
    p.add_argument("--phase-floor", type=non_negative, default=PHASE_FLOOR, metavar="F",
                   help="2022 models: each limb's local phase advances at least F times its style's capture rate "
                        "per frame (0: the paper's runtime, whose closed loop can stall)")



# --- helpers ------------------------------------------------------------------------------------

def progress(args) -> bool:
    """Progress bars: unless ``--quiet``, and only on the process that reports (``--distributed``)."""
    if getattr(args, "distributed", False):
        from jaxstyle.train import shard

        if not shard.is_writer():
            return False
    return not args.quiet


def _cpu_name() -> str:
    """The CPU's model name (Linux), else what :mod:`platform` knows."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def machine() -> str:
    import jax

    return (f"{_cpu_name()}, {os.cpu_count()} cores, jax {jax.__version__} on "
            f"{jax.devices()[0].platform} x {jax.device_count()}")


def elapsed(t0: float) -> str:
    s = time.perf_counter() - t0
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min"


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


def written(run: Run, title: str, files: Sequence[Path]) -> None:
    run.say(f"{title}:")
    for f in files:
        run.say(f"  {f}")
